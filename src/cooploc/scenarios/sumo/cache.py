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
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from cooploc.scenarios.sumo.params import GRID, TRAFFIC_KEYS, SumoParams
from cooploc.scenarios.sumo.simulation import Traffic, _require_sumo, network_path, simulate_traffic

__all__ = ["CACHE_FORMAT", "cache_dir", "cache_key", "cache_path", "traffic"]

CACHE_FORMAT = 3  # bump when the cached arrays change meaning


def cache_dir() -> Path:
    """Folder of the traffic cache: $COOPLOC_CACHE_DIR/sumo, else the user cache dir."""
    root = os.environ.get("COOPLOC_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        root = os.path.join(base, "cooploc")
    return Path(root) / "sumo"


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def cache_key(params: SumoParams, seed: int) -> str:
    """SHA-256 over the network file, the SUMO version, the seed and `TRAFFIC_KEYS`."""
    sumo, _ = _require_sumo()
    source = _file_digest(network_path(params.network)) if params.network != GRID else "netgenerate"
    payload = {"format": CACHE_FORMAT, "sumo": sumo.__version__, "network_file": source,
               "seed": int(seed), **{k: getattr(params, k) for k in TRAFFIC_KEYS}}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


def cache_path(params: SumoParams, seed: int) -> Path:
    """The cache file of the traffic of `params` and `seed`."""
    return cache_dir() / f"{params.network}-{params.regulation}-{cache_key(params, seed)}.npz"


def traffic(params: SumoParams, seed: int, *, use_cache: bool = True) -> Traffic:
    """The traffic of `params` and `seed`: from the cache, or simulated and cached."""
    path = cache_path(params, seed)
    if use_cache and path.is_file():
        try:
            return Traffic.load(path)
        except (OSError, ValueError, KeyError):  # a damaged file: simulate again
            pass
    result = simulate_traffic(params, seed)
    if use_cache:
        result.save(path)
    return result
