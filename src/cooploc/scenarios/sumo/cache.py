"""The on-disk cache of SUMO traffic: one ``.npz`` per network, parameters and seed.

Everything SUMO contributes to a `sumo-*` recording (network build, demand,
simulation, feature geometry — `Traffic`) is deterministic for its parameters and
traffic seed, while the sensors (Brambilla et al. 2020 §VI-A: GNSS zones, V2F) are
drawn fresh in every run. So the traffic is simulated once and kept as one ``.npz``
per key: a SHA-256 over the network file, the SUMO version, the seed, `CACHE_FORMAT`
and every parameter that changes the traffic (`TRAFFIC_KEYS`) — never the sensor
parameters, so sensor sweeps and Monte Carlo runs on a fixed `traffic_seed` reuse it.

The folder is ``$COOPLOC_CACHE_DIR/sumo`` if that variable is set, else
``$XDG_CACHE_HOME/cooploc/sumo`` (``~/.cache/cooploc/sumo``). Writes are atomic
(`Traffic.save`), so parallel workers may share the folder; a damaged file is
simulated again; deleting the folder is always safe. Bump `CACHE_FORMAT` whenever the
cached arrays change meaning.

The folder is bounded: after a file is written, the least recently used files are
deleted until the folder holds at most `cache_limit()` bytes —
``$COOPLOC_SUMO_CACHE_LIMIT`` (bytes, or with a suffix K, M, G, T: ``500M``, ``10G``;
``0`` keeps only the newest file), default `DEFAULT_CACHE_LIMIT` (2 GB). "Used" is the
file's modification time, which a cache hit refreshes (atime is unreliable on
``noatime`` mounts). The file just written is never deleted, even if it alone is
larger than the limit. A worker that loses a race with another one's eviction finds
no file (or a damaged one) and simulates again.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
from pathlib import Path

from cooploc.errors import ConfigError
from cooploc.scenarios.sumo.params import GRID, TRAFFIC_KEYS, SumoParams
from cooploc.scenarios.sumo.simulation import (
    GRID_OPTIONS,
    PEDESTRIAN_OPTIONS,
    Traffic,
    _require_sumo,
    network_file,
    simulate_traffic,
)

__all__ = ["CACHE_FORMAT", "CACHE_LIMIT_VARIABLE", "DEFAULT_CACHE_LIMIT", "cache_dir", "cache_key",
           "cache_limit", "cache_path", "evict", "traffic"]

# bump when the cached arrays change meaning (4: vehicle heading, junctions; 5: walking areas
# and crossings on real networks without them, so that pedestrians no longer jump)
CACHE_FORMAT = 5
CACHE_LIMIT_VARIABLE = "COOPLOC_SUMO_CACHE_LIMIT"
DEFAULT_CACHE_LIMIT = 2 * 1024**3  # bytes
_UNITS = {"": 1, "K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}


def cache_dir() -> Path:
    """Folder of the traffic cache: $COOPLOC_CACHE_DIR/sumo, else the user cache dir."""
    root = os.environ.get("COOPLOC_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        root = os.path.join(base, "cooploc")
    return Path(root) / "sumo"


def cache_limit() -> int:
    """Most bytes the cache folder keeps: ``$COOPLOC_SUMO_CACHE_LIMIT`` or `DEFAULT_CACHE_LIMIT`."""
    text = os.environ.get(CACHE_LIMIT_VARIABLE, "").strip()
    if not text:
        return DEFAULT_CACHE_LIMIT
    match = re.fullmatch(r"(\d+(?:\.\d*)?)\s*([KMGT]?)I?B?", text.upper())
    if match is None:
        raise ConfigError(f"{CACHE_LIMIT_VARIABLE}={text!r}: must be a size in bytes, "
                          "optionally with a suffix K, M, G or T (e.g. 500M, 10G)")
    return int(float(match[1]) * _UNITS[match[2]])


def evict(folder: Path, limit: int, keep: Path | None = None) -> list[Path]:
    """Delete the least recently used ``.npz`` files of `folder` until it holds at most
    `limit` bytes, never `keep`; returns the deleted files, oldest first."""
    entries = []
    for path in folder.glob("*.npz"):
        with contextlib.suppress(FileNotFoundError):  # another worker evicted it meanwhile
            stat = path.stat()
            entries.append((stat.st_mtime_ns, path.name, path, stat.st_size))
    total = sum(e[3] for e in entries)
    deleted = []
    for _, _, path, size in sorted(entries):
        if total <= limit:
            break
        if keep is not None and path == keep:
            continue
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            deleted.append(path)
        total -= size
    return deleted


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def cache_key(params: SumoParams, seed: int) -> str:
    """SHA-256 over the network file and `PEDESTRIAN_OPTIONS` (the grid: its netgenerate
    options), the SUMO version, the seed and `TRAFFIC_KEYS`."""
    sumo, _ = _require_sumo()
    source = (" ".join((_file_digest(network_file(params.network)), *PEDESTRIAN_OPTIONS))
              if params.network != GRID else " ".join(("netgenerate", *GRID_OPTIONS)))
    payload = {"format": CACHE_FORMAT, "sumo": sumo.__version__, "network_file": source,
               "seed": int(seed), **{k: getattr(params, k) for k in TRAFFIC_KEYS}}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


def cache_path(params: SumoParams, seed: int) -> Path:
    """The cache file of the traffic of `params` and `seed`."""
    name = params.network
    if params.own_network:  # a path: its file name, in characters any file system takes
        name = "own-" + re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(name).name)[:40]
    return cache_dir() / f"{name}-{params.regulation}-{cache_key(params, seed)}.npz"


def traffic(params: SumoParams, seed: int, *, use_cache: bool = True) -> Traffic:
    """The traffic of `params` and `seed`: from the cache, or simulated and cached."""
    path = cache_path(params, seed)
    limit = cache_limit() if use_cache else 0  # a bad limit is refused before SUMO runs
    if use_cache and path.is_file():
        try:
            result = Traffic.load(path)
        except (OSError, ValueError, KeyError):  # a damaged file: simulate again
            pass
        else:
            with contextlib.suppress(OSError):
                os.utime(path)  # used now: the last to be evicted
            return result
    result = simulate_traffic(params, seed)
    if use_cache:
        result.save(path)
        evict(path.parent, limit, keep=path)
    return result
