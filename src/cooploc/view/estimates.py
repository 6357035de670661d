"""The estimates `cooploc run` keeps for the viewer, and their file `estimates.parquet`.

A results folder holds errors for every run but not the estimates themselves; the
viewer (`cooploc view`) needs the means and covariances, and which feature each V2F
row was given. `kept_estimates(recording, estimates)` slims one estimator's per-step
estimates of a run to exactly that: the vehicle and feature `StateSet`s and, in
`Estimate.info`, only ``set_valued`` and ``v2f_association`` (for estimators that
start tracks of their own, ``v2f_track`` is turned into the true feature each track
stands for, `metrics.track_identities`, so every estimator's decisions read alike).
The runner keeps them for run 0 (`RunResult.estimates`); `write_estimates` stores
them, `read_estimates` reads them back.

``estimates.parquet`` — one row per run × estimator × step × entity, plus one row
per V2F measurement row where the estimator decided an association:

=============  ==============  ===========================================================
column         type            meaning
=============  ==============  ===========================================================
run            int64           Monte Carlo run (the runner keeps run 0)
estimator      string          registered estimator name
step           int64           k
kind           string          ``vehicle``, ``feature`` or ``v2f`` (an association row)
id             int64           entity id; for ``v2f`` the row index in the frame's V2F batch
mean           list<double>    state mean (SI units, the scenario's layout); null for ``v2f``
cov            list<double>    state covariance, row-major dx × dx; null for ``v2f``
decision       int64           ``v2f`` only: the decided feature id, −1 clutter/undecided
set_valued     bool            the estimator's vehicle ids are slots, not identities
=============  ==============  ===========================================================

The recording itself is not stored: it is regenerated exactly from ``config.toml``
(scenario, parameters, seed) by `cooploc.experiment.run_recording`.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.metrics import track_identities
from cooploc.types import Estimate, Recording, StateSet

__all__ = ["ESTIMATES_FILE", "kept_estimates", "read_estimates", "write_estimates"]

ESTIMATES_FILE = "estimates.parquet"
_KEPT_INFO = ("set_valued", "v2f_association")


def kept_estimates(recording: Recording, estimates: Sequence[Estimate]) -> list[Estimate]:
    """One estimator's estimates of a run with `info` slimmed to what the viewer reads."""
    tracks = [e.info.get("v2f_track") for e in estimates]
    identity: dict[int, int] = {}
    if any(t is not None for t in tracks):
        used = [k for k, t in enumerate(tracks) if t is not None]
        identity = track_identities([np.asarray(tracks[k]) for k in used],
                                    [recording.truth.origin[k].get("v2f", np.zeros(0, np.int64))
                                     for k in used])
    out = []
    for estimate, track in zip(estimates, tracks, strict=True):
        info = {key: estimate.info[key] for key in _KEPT_INFO if key in estimate.info}
        if track is not None:
            info["v2f_association"] = np.array([identity.get(int(t), -1) for t in track], np.int64)
        out.append(dataclasses.replace(estimate, info=info))
    return out


def _rows(run: int, name: str, estimates: Sequence[Estimate]) -> dict[str, list]:
    cols: dict[str, list] = {c: [] for c in ("run", "estimator", "step", "kind", "id", "mean", "cov",
                                             "decision", "set_valued")}

    def add(k: int, kind: str, ids: np.ndarray, mean: list | None, cov: list | None,
            decision: list | None, set_valued: bool) -> None:
        n = len(ids)
        cols["run"] += [run] * n
        cols["estimator"] += [name] * n
        cols["step"] += [k] * n
        cols["kind"] += [kind] * n
        cols["id"] += [int(i) for i in ids]
        cols["mean"] += mean if mean is not None else [None] * n
        cols["cov"] += cov if cov is not None else [None] * n
        cols["decision"] += decision if decision is not None else [None] * n
        cols["set_valued"] += [set_valued] * n

    for k, e in enumerate(estimates):
        set_valued = bool(e.info.get("set_valued", False))
        for kind, states in (("vehicle", e.vehicles), ("feature", e.features)):
            if states is not None and len(states):
                add(k, kind, states.ids, states.mean.tolist(),
                    states.cov.reshape(len(states), -1).tolist(), None, set_valued)
        decided = e.info.get("v2f_association")
        if decided is not None and len(decided):
            decided = np.asarray(decided, np.int64)
            add(k, "v2f", np.arange(decided.size), None, None, decided.tolist(), set_valued)
    return cols


def write_estimates(kept: Mapping[int, Mapping[str, Sequence[Estimate]]],
                    folder: str | os.PathLike[str]) -> Path | None:
    """Write ``estimates.parquet`` from {run: {estimator: estimates}}; None if nothing is kept."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = pa.schema([("run", pa.int64()), ("estimator", pa.string()), ("step", pa.int64()),
                        ("kind", pa.string()), ("id", pa.int64()), ("mean", pa.list_(pa.float64())),
                        ("cov", pa.list_(pa.float64())), ("decision", pa.int64()),
                        ("set_valued", pa.bool_())])
    tables = [pa.table(_rows(run, name, estimates), schema=schema)
              for run, by_name in kept.items() for name, estimates in by_name.items()]
    if not tables:
        return None
    path = Path(folder) / ESTIMATES_FILE
    pq.write_table(pa.concat_tables(tables), path)
    return path


def _by_step(part, kind: str, n_steps: int) -> list[StateSet | None]:
    """The `kind` rows of one estimator's table as one StateSet per step (None: no rows)."""
    import pyarrow.compute as pc

    rows = part.filter(pc.equal(part["kind"], kind))
    out: list[StateSet | None] = [None] * n_steps
    if rows.num_rows == 0:
        return out
    step = rows["step"].to_numpy()
    ids = rows["id"].to_numpy().astype(np.int64)
    flat = pc.list_flatten(rows["mean"]).to_numpy()
    dim = flat.size // rows.num_rows
    mean = flat.reshape(-1, dim)
    cov = pc.list_flatten(rows["cov"]).to_numpy().reshape(-1, dim, dim)
    order = np.argsort(step, kind="stable")
    bounds = np.searchsorted(step[order], np.arange(n_steps + 1))
    for k in range(n_steps):
        at = order[bounds[k]:bounds[k + 1]]
        if at.size:
            out[k] = StateSet(ids[at], mean[at], cov[at])
    return out


def read_estimates(folder: str | os.PathLike[str], run: int, n_steps: int,
                   vehicle_dim: int) -> dict[str, list[Estimate]] | None:
    """{estimator: estimates of each step} of `run` from ``estimates.parquet``, or None when
    the folder has no such file or it does not hold that run."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    path = Path(folder) / ESTIMATES_FILE
    if not path.is_file():
        return None
    try:
        table = pq.read_table(path, filters=[("run", "=", run)])
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise InvalidInputError(f"{path}: not a readable estimates table ({exc})") from None
    if table.num_rows == 0:
        return None
    out: dict[str, list[Estimate]] = {}
    for name in pc.unique(table["estimator"]).to_pylist():
        part = table.filter(pc.equal(table["estimator"], name))
        set_valued = bool(pc.any(part["set_valued"]).as_py())
        vehicles = _by_step(part, "vehicle", n_steps)
        features = _by_step(part, "feature", n_steps)
        v2f = part.filter(pc.equal(part["kind"], "v2f"))
        v2f_step, v2f_row = v2f["step"].to_numpy(), v2f["id"].to_numpy()
        v2f_decision = v2f["decision"].to_numpy(zero_copy_only=False)
        estimates = []
        for k in range(n_steps):
            info: dict = {"set_valued": True} if set_valued else {}
            at = v2f_step == k
            if at.any():
                decided = np.full(int(v2f_row[at].max()) + 1, -1, np.int64)
                decided[v2f_row[at]] = v2f_decision[at].astype(np.int64)
                info["v2f_association"] = decided
            estimates.append(Estimate(vehicles[k] or StateSet.empty(vehicle_dim), features[k], info))
        out[name] = estimates
    return out
