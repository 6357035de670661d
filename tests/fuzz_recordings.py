"""Mutations of saved recordings and what loading + estimating them gives (issue 16, item 9).

Used by `tests/test_fuzz_recordings.py` (hypothesis picks the seeds) and run as a script
to print the counts of the closing note::

    PYTHONPATH=src python tests/fuzz_recordings.py [--per-family N]

It uses only `save_recording`, `load_recording`, `make_estimator` and
`experiment.estimate`, so the same script measures an older checkout too
(``PYTHONPATH=/work/main/src``).

Three families of mutation of one saved recording per preset family:

- ``hand``: the named corruptions of `HAND` (the issue's list and its neighbours);
- ``structural``: a column dropped, retyped, nulled, truncated or its rows duplicated,
  dropped or reordered; a setup.json field deleted or given a value of another type;
- ``semantic``: well-formed values that cannot be right: ids, kinds, times, dt, n_steps,
  prior ids, covariance and measurement scales.

Each mutated folder is loaded; if it loads, every estimator that accepts its setup runs
on it. Outcomes: ``refused`` (a `CooplocError` while loading or constructing),
``ran`` (finite estimates), ``estimator_error`` (a `CooplocError` from a step),
``crash`` (any other exception) and ``nonfinite`` (NaN/inf in an estimate without an
error). The last two are the failures.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from cooploc.errors import ConfigError, CooplocError
from cooploc.experiment import estimate
from cooploc.io import load_recording, save_recording
from cooploc.registry import estimators, get_preset, make_estimator

#: one small recording per preset family (steps kept short: every estimator runs on it)
FAMILIES = {
    "froehle2018": ("froehle2018", {"n_steps": 4}),
    "zhang2016": ("zhang2016-cv", {"n_steps": 4}),
    "gulati": ("gulati-2v", {"n_steps": 4}),
    "aoa-grid": ("aoa-grid-tracking", {"n_steps": 3}),
    "brambilla": ("brambilla-road", {"n_steps": 4}),
    "sumo": ("sumo-grid-tlr", None),
}
#: particle counts small enough for a fuzz run (the numbers do not matter, only failure)
FAST_PARAMS = {"rsu-bp": {"n_particles": 40}, "sme-pf": {"n_particles": 60},
               "icp-da-pf": {"n_particles": 40}}
#: slow on a many-vehicle AoA grid at any size; the contract suite covers them
SKIP = {("aoa-grid", "plbp")}
FILES = ("frames.parquet", "measurements.parquet", "truth_vehicles.parquet",
         "truth_features.parquet", "sensor_poses.parquet")
FAILURES = ("crash", "nonfinite")


def family_recording(family: str, folder: Path) -> Path:
    """Save the family's small recording into `folder` (SUMO: the tests' tiny grid)."""
    preset_name, overrides = FAMILIES[family]
    preset = get_preset(preset_name)
    if family == "sumo":
        from cooploc.scenarios import sumo

        params = preset.params.with_overrides(sumo.TINY_GRID)
    else:
        params = preset.params.with_overrides(overrides)
    recording = preset.generate(np.random.default_rng(7), params)
    try:
        return save_recording(recording, folder)
    except CooplocError:  # a checkout that cannot save infinite radar ranges: a finite stand-in
        sensors = {kind: (dataclasses.replace(model, max_range=1e12)
                          if getattr(model, "max_range", 0.0) == np.inf else model)
                   for kind, model in recording.setup.sensors.items()}
        setup = dataclasses.replace(recording.setup, sensors=sensors)
        return save_recording(dataclasses.replace(recording, setup=setup), folder)


# ----------------------------------------------------------------------------
# editing a saved folder
# ----------------------------------------------------------------------------


def read_setup(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "setup.json").read_text())


def write_setup(folder: Path, data: dict[str, Any]) -> None:
    (folder / "setup.json").write_text(json.dumps(data))


def set_setup(folder: Path, key: str, value: Any) -> None:
    data = read_setup(folder)
    if value is KeyError:
        data.pop(key, None)
    else:
        data[key] = value
    write_setup(folder, data)


def edit_column(folder: Path, file: str, column: str, edit: Callable[[list], list],
                type_: pa.DataType | None = None) -> None:
    table = pq.read_table(folder / file)
    if column not in table.column_names:
        return
    values = edit(table.column(column).to_pylist())
    index = table.column_names.index(column)
    array = pa.array(values, type_ or table.schema.field(column).type)
    pq.write_table(table.set_column(index, column, array), folder / file)


def filter_rows(folder: Path, file: str, keep: Callable[[pa.Table], Any]) -> None:
    table = pq.read_table(folder / file)
    pq.write_table(table.filter(keep(table)), folder / file)


def first_row(folder: Path, kind: str) -> int | None:
    kinds = pq.read_table(folder / "measurements.parquet").column("kind").to_pylist()
    return kinds.index(kind) if kind in kinds else None


def set_row(folder: Path, kind: str, column: str, value: Any) -> None:
    i = first_row(folder, kind)
    if i is not None:
        edit_column(folder, "measurements.parquet", column,
                    lambda values: [*values[:i], value, *values[i + 1:]])


def first_kind(folder: Path) -> str:
    return pq.read_table(folder / "measurements.parquet").column("kind")[0].as_py()


def rename_kind(folder: Path, old: str, new: str) -> None:
    edit_column(folder, "frames.parquet", "batch_kinds",
                lambda v: [[new if k == old else k for k in ks] for ks in v])
    edit_column(folder, "measurements.parquet", "kind", lambda v: [new if k == old else k for k in v])


def set_times(folder: Path, times: Callable[[int], list[float]]) -> None:
    n = pq.read_table(folder / "frames.parquet").num_rows
    edit_column(folder, "frames.parquet", "t", lambda v: times(n))
    table = pq.read_table(folder / "measurements.parquet")
    pq.write_table(table.drop_columns(["t"]), folder / "measurements.parquet")


def set_prior_ids(folder: Path, ids: Callable[[list[int]], list[int]]) -> None:
    data = read_setup(folder)
    data["vehicle_prior"]["ids"] = ids(data["vehicle_prior"]["ids"])
    write_setup(folder, data)


def scale_list_column(folder: Path, file: str, column: str, factor: float) -> None:
    edit_column(folder, file, column, lambda v: [[x * factor for x in row] for row in v])


def empty_truth_features(folder: Path) -> None:
    table = pq.read_table(folder / "truth_features.parquet")
    pq.write_table(table.slice(0, 0), folder / "truth_features.parquet")


def drop_step(folder: Path, file: str, step: int) -> None:
    filter_rows(folder, file, lambda t: pc.not_equal(t.column("step"), step))


def wrong_batch_dims(folder: Path) -> None:
    edit_column(folder, "frames.parquet", "batch_dims", lambda v: [[d + 1 for d in ds] for ds in v])


#: the hand-made corruptions: name → edit of a saved folder
HAND: dict[str, Callable[[Path], None]] = {
    "n_steps true": lambda f: set_setup(f, "n_steps", True),
    "n_steps off by one": lambda f: set_setup(f, "n_steps", read_setup(f)["n_steps"] + 1),
    "dt fast": lambda f: set_setup(f, "dt", "fast"),
    "dt 7": lambda f: set_setup(f, "dt", 7),
    "dt missing": lambda f: set_setup(f, "dt", KeyError),
    "setup without sensors": lambda f: set_setup(f, "sensors", KeyError),
    "sensors empty": lambda f: set_setup(f, "sensors", {}),
    "infrastructure ids without poses": lambda f: set_setup(f, "infrastructure_ids", [900, 901]),
    "prior id of no vehicle": lambda f: set_prior_ids(f, lambda ids: [*ids[:-1], 987654] if ids else ids),
    "gnss subject of no vehicle": lambda f: set_row(f, "gnss", "subject", 987654),
    "gnss sensor of no vehicle": lambda f: set_row(f, "gnss", "sensor", 987654),
    "v2f sensor of no vehicle": lambda f: set_row(f, "v2f", "sensor", 987654),
    "radar sensor of no vehicle": lambda f: set_row(f, "radar", "sensor", 987654),
    "origin of no entity": lambda f: set_row(f, first_kind(f), "origin", 987654),
    "kind GNSS undeclared": lambda f: rename_kind(f, "gnss", "GNSS"),
    "first kind undeclared": lambda f: rename_kind(f, first_kind(f), "lidar"),
    "times reversed": lambda f: set_times(f, lambda n: [float(n - k) for k in range(n)]),
    "times constant": lambda f: set_times(f, lambda n: [1.0] * n),
    "times 10x dt": lambda f: set_times(f, lambda n: [10.0 * read_setup(f)["dt"] * k for k in range(n)]),
    "truth missing a step": lambda f: drop_step(f, "truth_vehicles.parquet", 1),
    "truth missing the last step": lambda f: drop_step(f, "truth_vehicles.parquet", -1 + pq.read_table(
        f / "frames.parquet").num_rows),
    "truth features missing a step": lambda f: drop_step(f, "truth_features.parquet", 1),
    "empty truth_features": empty_truth_features,
    "wrong batch_dims": wrong_batch_dims,
    "frames missing a step": lambda f: drop_step(f, "frames.parquet", 1),
    "measurements of a missing step": lambda f: drop_step(f, "measurements.parquet", 0),
    "covariances x1e-30": lambda f: scale_list_column(f, "measurements.parquet", "cov", 1e-30),
    "covariances x1e12": lambda f: scale_list_column(f, "measurements.parquet", "cov", 1e12),
    "z x1000": lambda f: scale_list_column(f, "measurements.parquet", "z", 1e3),
    "no measurements": lambda f: filter_rows(f, "measurements.parquet",
                                             lambda t: pc.equal(t.column("row"), -1)),
    "vehicles empty everywhere": lambda f: edit_column(f, "frames.parquet", "vehicles",
                                                       lambda v: [[] for _ in v]),
    "truth all absent": lambda f: edit_column(f, "truth_vehicles.parquet", "present",
                                              lambda v: [False] * len(v)),
}


# ----------------------------------------------------------------------------
# random mutations
# ----------------------------------------------------------------------------


def structural(folder: Path, rng: np.random.Generator) -> str:
    """One random structural mutation; returns its description."""
    if rng.random() < 0.25:
        data = read_setup(folder)
        key = str(rng.choice(sorted(data)))
        value = [KeyError, None, "x", -1, 1e308, [], {}, True, [[1.0]]][rng.integers(9)]
        set_setup(folder, key, value)
        return f"setup.json {key} = {value!r}"
    file = str(rng.choice(FILES))
    table = pq.read_table(folder / file)
    if not table.column_names:
        return f"{file}: no columns"
    column = str(rng.choice(table.column_names))
    how = int(rng.integers(6))
    n = table.num_rows
    if how == 0:
        pq.write_table(table.drop_columns([column]), folder / file)
        return f"{file}: drop {column}"
    if how == 1:
        array = pa.array([str(x) for x in table.column(column).to_pylist()], pa.string())
        pq.write_table(table.set_column(table.column_names.index(column), column, array), folder / file)
        return f"{file}: {column} as strings"
    if how == 2 and n:
        values = table.column(column).to_pylist()
        values[int(rng.integers(n))] = None
        array = pa.array(values, table.schema.field(column).type)
        pq.write_table(table.set_column(table.column_names.index(column), column, array), folder / file)
        return f"{file}: a null in {column}"
    if how == 3 and n:
        rows = rng.integers(n, size=int(rng.integers(1, n + 1)))
        pq.write_table(table.take(pa.array(np.sort(rows))), folder / file)
        return f"{file}: rows resampled ({rows.size} of {n})"
    if how == 4 and n:
        values = table.column(column).to_pylist()
        i = int(rng.integers(n))
        if isinstance(values[i], list):
            values[i] = values[i][: max(len(values[i]) - 1, 0)] if rng.random() < 0.5 else values[i] * 2
        elif isinstance(values[i], float):
            values[i] = [np.nan, np.inf, -np.inf, 1e300, -0.0][rng.integers(5)]
        elif isinstance(values[i], bool):
            values[i] = not values[i]
        elif isinstance(values[i], int):
            values[i] = [-1, -(2**62), 2**62, values[i] + 1][rng.integers(4)]
        try:
            array = pa.array(values, table.schema.field(column).type)
        except (pa.ArrowException, OverflowError):
            return f"{file}: {column} unchanged"
        pq.write_table(table.set_column(table.column_names.index(column), column, array), folder / file)
        return f"{file}: {column}[{i}] edited"
    pq.write_table(table.slice(0, 0), folder / file)
    return f"{file}: emptied"


def semantic(folder: Path, rng: np.random.Generator) -> str:
    """One random well-formed but meaningless change; returns its description."""
    frames = pq.read_table(folder / "frames.parquet")
    n = frames.num_rows
    how = int(rng.integers(10))
    if how == 0:
        column = str(rng.choice(["sensor", "subject", "origin"]))
        table = pq.read_table(folder / "measurements.parquet")
        if table.num_rows:
            i = int(rng.integers(table.num_rows))
            value = int(rng.choice([-1, 0, 1, 5, 100, 1000, 10**6, -7]))
            edit_column(folder, "measurements.parquet", column,
                        lambda v: [*v[:i], value, *v[i + 1:]])
            return f"measurements {column}[{i}] = {value}"
    if how == 1:
        kinds = sorted({k for ks in frames.column("batch_kinds").to_pylist() for k in ks})
        if kinds:
            old = str(rng.choice(kinds))
            new = str(rng.choice([k for k in [*kinds, "imu", "GNSS", "aoa", "radar"] if k != old]))
            rename_kind(folder, old, new)
            return f"kind {old} → {new}"
    if how == 2:
        factor = float(rng.choice([-1.0, 0.0, 0.5, 3.0, 1e6]))
        set_times(folder, lambda m: [factor * read_setup(folder)["dt"] * k for k in range(m)])
        return f"times x{factor}"
    if how == 3:
        dt = float(rng.choice([1e-9, 0.01, 7.0, 1e6]))
        set_setup(folder, "dt", dt)
        return f"dt = {dt}"
    if how == 4:
        steps = int(rng.choice([1, n - 1, n + 1, 2 * n, 10**6]))
        set_setup(folder, "n_steps", steps)
        return f"n_steps = {steps}"
    if how == 5:
        value = int(rng.choice([-1, 0, 5, 1000, 10**6]))
        set_prior_ids(folder, lambda ids: [value, *ids[1:]] if ids else ids)
        return f"prior id {value}"
    if how == 6:
        file, column = (("measurements.parquet", str(rng.choice(["z", "cov"]))) if rng.random() < 0.7
                        else ("truth_vehicles.parquet", "x_0"))
        factor = float(rng.choice([1e-12, 1e-6, 1e3, 1e6, 1e12]))
        if column == "x_0":
            edit_column(folder, file, column, lambda v: [x * factor for x in v])
        else:
            scale_list_column(folder, file, column, factor)
        return f"{file} {column} x{factor}"
    if how == 7:
        ids = [int(rng.choice([100, 101, 0, 1, 5, 1000]))
               for _ in range(int(rng.integers(0, 3)))]
        set_setup(folder, "infrastructure_ids", ids)
        return f"infrastructure_ids = {ids}"
    if how == 8:
        vehicles = frames.column("vehicles").to_pylist()
        k = int(rng.integers(n))
        vehicles[k] = vehicles[k][1:] if rng.random() < 0.5 else [*vehicles[k], 4242]
        edit_column(folder, "frames.parquet", "vehicles", lambda v: vehicles)
        return f"frames vehicles at step {k} changed"
    data = read_setup(folder)
    probability = float(rng.choice([1e-9, 0.5, 1.0]))
    rate = float(rng.choice([0.0, 3.0, 1e6]))
    data.update(detection_probability=probability, clutter_rate=rate)
    write_setup(folder, data)
    return f"P_D = {probability}, clutter = {rate}"


# ----------------------------------------------------------------------------
# running a mutated folder
# ----------------------------------------------------------------------------


def run_folder(folder: Path, family: str) -> list[tuple[str, str, str]]:
    """(estimator or "load", outcome, detail) of loading `folder` and running every estimator."""
    try:
        recording = load_recording(folder)
    except CooplocError as exc:
        return [("load", "refused", str(exc)[:200])]
    except Exception as exc:
        return [("load", "crash", f"{type(exc).__name__}: {exc}"[:300])]
    out = []
    for name, cls in sorted(estimators().items()):
        if (family, name) in SKIP:
            continue
        rng = np.random.default_rng(0)
        try:
            params = cls.Params().with_overrides(FAST_PARAMS.get(name, {}))
            estimator = make_estimator(name, recording.setup, params, rng, truth=recording.truth)
        except (ConfigError, CooplocError) as exc:
            out.append((name, "refused", str(exc)[:200]))
            continue
        except Exception as exc:
            out.append((name, "crash", f"construct: {type(exc).__name__}: {exc}"[:300]))
            continue
        try:
            estimates = estimate(estimator, recording)
        except CooplocError as exc:
            out.append((name, "estimator_error", f"{type(exc).__name__}: {exc}"[:200]))
            continue
        except Exception as exc:
            where = traceback.extract_tb(exc.__traceback__)[-1]
            out.append((name, "crash", f"{type(exc).__name__}: {exc} ({Path(where.filename).name}:"
                                       f"{where.lineno})"[:300]))
            continue
        finite = all(np.isfinite(e.vehicles.mean).all() and np.isfinite(e.vehicles.cov).all()
                     and (e.features is None or (np.isfinite(e.features.mean).all()
                                                 and np.isfinite(e.features.cov).all()))
                     for e in estimates)
        out.append((name, "ran" if finite else "nonfinite", ""))
    return out


def mutate(base: Path, work: Path, family: str, kind: str, seed: int | str) -> tuple[str, list]:
    """Copy `base` to `work`, apply one mutation of `kind`, run it; (description, outcomes)."""
    if work.exists():
        shutil.rmtree(work)
    shutil.copytree(base, work)
    try:
        if kind == "hand":
            HAND[str(seed)](work)
            what = str(seed)
        else:
            what = (structural if kind == "structural" else semantic)(work, np.random.default_rng(
                [int(seed), sorted(FAMILIES).index(family)]))
    except (pa.ArrowException, ValueError, TypeError, KeyError, IndexError) as exc:
        return f"mutation not applicable ({type(exc).__name__})", []
    return what, run_folder(work, family)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="fuzz counts of saved-recording mutations")
    parser.add_argument("--per-family", type=int, default=20, help="random mutations per family and kind")
    parser.add_argument("--families", nargs="*", default=sorted(FAMILIES))
    parser.add_argument("--verbose", action="store_true", help="print every failure")
    args = parser.parse_args(argv)
    counts: dict[str, Counter] = {kind: Counter() for kind in ("hand", "structural", "semantic")}
    cases: dict[str, Counter] = {kind: Counter() for kind in counts}
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        for family in args.families:
            base = family_recording(family, Path(tmp) / family / "base")
            for kind in counts:
                seeds = list(HAND) if kind == "hand" else range(args.per_family)
                for seed in seeds:
                    what, outcomes = mutate(base, Path(tmp) / family / "case", family, kind, seed)
                    worst = next((o for o in FAILURES if any(r[1] == o for r in outcomes)), "clean")
                    cases[kind][worst] += 1
                    refused = bool(outcomes) and outcomes[0][:2] == ("load", "refused")
                    cases[kind]["refused at load" if refused else "loaded"] += 1
                    for name, outcome, detail in outcomes:
                        counts[kind][outcome] += 1
                        if outcome in FAILURES:
                            failures.append((kind, family, what, name, outcome, detail))
    for kind in counts:
        print(f"{kind:10s} cases: {sum(cases[kind][o] for o in ('clean', *FAILURES))} "
              f"{dict(cases[kind])}  estimator-runs: {dict(counts[kind])}")
    if args.verbose:
        for failure in failures:
            print(" | ".join(failure))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
