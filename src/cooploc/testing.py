"""The estimator contract (STYLE §9), runnable on any estimator: `check_estimator`.

Every estimator — cooploc's own and a plug-in's — must pass these checks. Each runs on
a short recording of the estimator's own `default_preset`:

- ``interface``: it declares `name`, `summary`, `Params` (valid defaults),
  `needs_truth`, `default_preset` (a registered preset) and `step`;
- ``valid_estimates``: one belief per present vehicle every step (ids equal to
  `frame.vehicles` as a set), means (n, dx) without NaN, SPD covariances; the
  estimate follows the data (not a constant);
- ``empty_frames``: frames without vehicles, without batches, and with empty batches;
- ``same_seed``: the same seed gives the same numbers;
- ``enter_and_leave``: vehicles that enter and leave (skipped for presets that cannot
  have 3 vehicles);
- ``froehle_traffic``: the suite's 3-vehicle traffic run (froehle2018 estimators);
- ``missed_detections_and_clutter``: P_D = 0.7 and 2 clutter rows per sensor and step
  (skipped for presets that cannot express them);
- ``long_run`` (slow): 2000 steps of a small version of the preset stay finite, and
  the second half is no less certain than the first;
- ``truth_only_to_references``: only a known-association reference (`needs_truth`)
  receives truth, and only its association (`AssociationTruth`);
- ``true_states_never_read``: replacing the true states by garbage changes nothing;
- ``sumo_traffic``: a tiny SUMO run where vehicles and pedestrians enter and leave
  (skipped without the ``sumo`` extra); an estimator whose sensors SUMO traffic lacks,
  or has in a form the method does not model, must refuse it with a clear `ConfigError`
  ("… needs …").

>>> from cooploc.testing import check_estimator
>>> check_estimator("gnss-kf")                   # doctest: +SKIP
{'interface': 'passed', 'valid_estimates': 'passed', ...}

`check_estimator` stops at the first failure with an `AssertionError` that names the
check; a check that cannot apply raises `CheckSkipped` inside and is reported as
skipped. `run_check` runs one check (what cooploc's own test suite parametrises
over); `on_preset(estimator, preset, overrides)` holds an estimator to the same checks
on another scenario's recordings. The recording surgery the checks use (`with_traffic`,
`with_empty_frames`) and the assertions (`assert_valid_estimate`, `assert_spd`) are
public, for tests of your own; `translated` moves a whole recording (e.g. to UTM
magnitudes) for invariance tests.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cooploc.errors import ConfigError
from cooploc.experiment import estimate
from cooploc.params import Params
from cooploc.registry import construct, get_estimator, get_preset, presets
from cooploc.types import AssociationTruth, Batch, Estimate, Frame, Recording, StateSet, Truth

__all__ = [
    "CHECKS",
    "CONTRACT_PARTICLES",
    "SMALL_STEPS",
    "TRAFFIC_ABSENT",
    "CheckSkipped",
    "assert_spd",
    "assert_state_set",
    "assert_valid_estimate",
    "check_estimator",
    "contract_params",
    "on_preset",
    "preset_recording",
    "run_check",
    "run_estimator",
    "translated",
    "with_empty_frames",
    "with_traffic",
]

#: Length of the short recordings of the checks: long enough for every estimator to
#: leave its start-up transient, short enough that the contract stays fast.
SMALL_STEPS = 40

#: The traffic pattern of the checks: the second vehicle enters at step 5, the third
#: leaves for steps 10–19 and comes back at step 20 (keys: vehicle ids of froehle2018).
TRAFFIC_ABSENT: dict[int, range] = {1: range(0, 5), 2: range(10, 20)}

#: the checks test behaviour, not accuracy: particle estimators run with at most this many
#: particles unless a check gives its own parameters (a default of thousands, chosen for
#: accuracy, would make the contract slow without testing more)
CONTRACT_PARTICLES = 2000
#: long runs check stability, not accuracy: fewer particles make degeneracy likelier
LONG_RUN_PARTICLES = 300
LONG_RUN_STEPS = 2000


class CheckSkipped(Exception):
    """A check that cannot apply to this estimator (the message says why)."""


# ----------------------------------------------------------------------------
# recordings and their surgery
# ----------------------------------------------------------------------------


def preset_recording(name: str, seed: Any, overrides: Mapping[str, Any] | None = None) -> Recording:
    """One run of preset `name` with parameter overrides, from `default_rng(seed)`."""
    preset = get_preset(name)
    params = preset.params.with_overrides(dict(overrides or {}))
    return preset.generate(np.random.default_rng(seed), params)


def _vehicle_rows(batch: Batch, origin: np.ndarray, absent: np.ndarray,
                  vehicle_ids: np.ndarray, feature_ids: np.ndarray) -> np.ndarray:
    """Mask of the rows that do not involve an absent vehicle (as sensor, subject or origin)."""
    keep = ~np.isin(batch.sensor, absent) & ~np.isin(batch.subject, absent)
    # origin is an entity id; it names a vehicle only where it is not a feature id
    origin_is_vehicle = np.isin(origin, vehicle_ids) & ~np.isin(origin, feature_ids)
    return keep & ~(origin_is_vehicle & np.isin(origin, absent))


def with_traffic(recording: Recording, absent: Mapping[int, Iterable[int]],
                 keep_prior: bool = False) -> Recording:
    """The same run with vehicles taken away at some steps.

    Rows measured by, about, or originating from an absent vehicle are removed from
    every batch (and from `Truth.origin`), links touching it are dropped, its true
    state is zeroed and `Truth.vehicle_present` is cleared. Unless `keep_prior`, the
    prior in the setup keeps only the vehicles present at step 0: a vehicle that enters
    later has no prior and is born from its first GNSS fix
    (`cooploc.estimators.base.birth_beliefs`). With `keep_prior` every vehicle keeps its
    step-0 prior (estimators predict it to the step where the vehicle enters).

    Parameters
    ----------
    recording : a run in which every vehicle is present at every step.
    absent : vehicle id → steps at which it is not on the road.
    """
    truth = recording.truth
    present = np.array(truth.vehicle_present)
    for vehicle, steps in absent.items():
        col = int(np.flatnonzero(truth.vehicle_ids == vehicle)[0])
        present[list(steps), col] = False
    frames, origins = [], []
    for k, frame in enumerate(recording.frames):
        gone = truth.vehicle_ids[~present[k]]
        batches, origin = {}, {}
        for kind, batch in frame.batches.items():
            rows = _vehicle_rows(batch, truth.origin[k][kind], gone, truth.vehicle_ids,
                                 truth.feature_ids)
            batches[kind] = batch.select(rows)
            origin[kind] = truth.origin[k][kind][rows]
        links = frame.links[~np.isin(frame.links, gone).any(axis=1)]
        vehicles = frame.vehicles[~np.isin(frame.vehicles, gone)]
        frames.append(Frame(k, frame.t, vehicles, batches, links))
        origins.append(origin)
    states = np.where(present[..., None], truth.vehicle_states, 0.0)
    heading = None if truth.vehicle_heading is None else np.where(present, truth.vehicle_heading, 0.0)
    new_truth = dataclasses.replace(truth, vehicle_states=states, vehicle_present=present,
                                    origin=origins, vehicle_heading=heading)
    prior = recording.setup.vehicle_prior
    at_start = prior.ids[np.isin(prior.ids, truth.vehicle_ids[present[0]])]
    setup = recording.setup if keep_prior else dataclasses.replace(
        recording.setup, vehicle_prior=prior.take(at_start))
    return Recording(setup, frames, new_truth)


#: sensor models whose rows are absolute positions (they move with a translation);
#: relative, radar-frame, odometry and angle rows do not
ABSOLUTE_POSITION_SENSORS = ("gnss-position", "anonymous-position")


def translated(recording: Recording, offset: Sequence[float]) -> Recording:
    """The same run with the world moved by `offset` (m, one entry per position axis).

    Moved: true vehicle and feature positions (present entries), priors, infrastructure
    sensor poses, and the position components of every row of a sensor in
    `ABSOLUTE_POSITION_SENSORS`. Relative measurements (V2F), radar rows (in the radar's
    own frame, whose pose moves), odometry and angles are unchanged, and so is
    `Setup.clutter_region` (a box in a sensor's frame or the world's, depending on the
    scenario; estimators use only its area).
    """
    setup, truth = recording.setup, recording.truth
    offset = np.asarray(offset, dtype=float)

    def move(states: np.ndarray, layout: Any, where: np.ndarray | None = None) -> np.ndarray:
        out = np.array(states, dtype=float)
        if layout is None or out.size == 0:
            return out
        shift = np.zeros(out.shape[-1])
        shift[list(layout.position)] = offset
        return out + (shift if where is None else where[..., None] * shift)

    def move_prior(prior: StateSet | None, layout: Any) -> StateSet | None:
        return None if prior is None else StateSet(prior.ids, move(prior.mean, layout), prior.cov)

    frames = []
    for frame in recording.frames:
        batches = {}
        for kind, batch in frame.batches.items():
            model = setup.sensors.get(kind)
            if getattr(model, "name", None) in ABSOLUTE_POSITION_SENSORS:
                shift = np.zeros(batch.dim)
                for column, index in enumerate(model.state_indices):
                    if index in setup.vehicle_layout.position:
                        shift[column] = offset[setup.vehicle_layout.position.index(index)]
                batch = Batch(batch.z + shift, batch.cov, batch.sensor, batch.subject)
            batches[kind] = batch
        frames.append(Frame(frame.k, frame.t, frame.vehicles, batches, frame.links))
    poses = np.array(truth.sensor_poses)
    poses[:, :2] += offset[:2]
    new_setup = dataclasses.replace(
        setup, vehicle_prior=move_prior(setup.vehicle_prior, setup.vehicle_layout),
        feature_prior=move_prior(setup.feature_prior, setup.feature_layout))
    new_truth = dataclasses.replace(
        truth, vehicle_states=move(truth.vehicle_states, setup.vehicle_layout, truth.vehicle_present),
        feature_states=move(truth.feature_states, setup.feature_layout, truth.feature_present),
        sensor_poses=poses)
    return Recording(new_setup, frames, new_truth)


def with_empty_frames(
    recording: Recording,
    no_vehicles: Sequence[int] = (0, 1, 15),
    no_batches: Sequence[int] = (5, 6, 7),
    empty_batches: Sequence[int] = (10, 11, 12),
) -> Recording:
    """The same run with degenerate frames at the given steps.

    no_vehicles : frames with no vehicle and no measurement (everybody off the road).
    no_batches : vehicles present, but no batch at all (a dropped radio packet).
    empty_batches : vehicles present, every batch kind there but with zero rows.
    """
    truth = recording.truth
    frames, origins = [], []
    for k, frame in enumerate(recording.frames):
        origin = dict(truth.origin[k])
        if k in no_vehicles:
            frame, origin = Frame(k, frame.t, np.zeros(0, np.int64)), {}
        elif k in no_batches:
            frame, origin = Frame(k, frame.t, frame.vehicles), {}
        elif k in empty_batches:
            batches = {kind: Batch.empty(batch.dim) for kind, batch in frame.batches.items()}
            frame = Frame(k, frame.t, frame.vehicles, batches)
            origin = {kind: np.zeros(0, np.int64) for kind in batches}
        frames.append(frame)
        origins.append(origin)
    return Recording(recording.setup, frames, dataclasses.replace(truth, origin=origins))


# ----------------------------------------------------------------------------
# running an estimator
# ----------------------------------------------------------------------------


def _estimator_class(estimator: type | str) -> type:
    return get_estimator(estimator) if isinstance(estimator, str) else estimator


def run_estimator(estimator: type | str, recording: Recording, seed: Any = 0,
                  params: Params | None = None) -> list[Estimate]:
    """Construct `estimator` (a registered name or a class; truth only if it needs it) and
    step it through `recording`; the per-step estimates (no smoothing)."""
    cls = _estimator_class(estimator)
    est = construct(cls, recording.setup, params if params is not None else contract_params(cls),
                    np.random.default_rng(seed), truth=recording.truth if cls.needs_truth else None)
    return estimate(est, recording, smooth=False)


def contract_params(cls: type, max_particles: int = CONTRACT_PARTICLES) -> Params:
    """`cls`'s default parameters, with at most `max_particles` particles where it has a
    ``n_particles`` parameter."""
    params = cls.Params()
    if "n_particles" in params.keys():
        params = params.with_overrides(
            {"n_particles": min(params.n_particles, max_particles)})  # type: ignore[attr-defined]
    return params


# ----------------------------------------------------------------------------
# assertions
# ----------------------------------------------------------------------------


def assert_spd(cov: np.ndarray, name: str = "cov") -> None:
    """Every matrix of `cov (n, d, d)` finite, symmetric and positive definite."""
    assert np.isfinite(cov).all(), f"{name} has non-finite entries"
    # symmetric up to round-off of a Joseph update (relative 1e-10)
    scale = np.abs(cov).max() if cov.size else 1.0
    np.testing.assert_allclose(cov, np.swapaxes(cov, -1, -2), rtol=0, atol=1e-10 * scale,
                               err_msg=f"{name} is not symmetric")
    if cov.size:
        assert (np.linalg.eigvalsh(cov) > 0).all(), f"{name} is not positive definite"


def assert_state_set(states: StateSet, dim: int, name: str) -> None:
    """Means (n, dim) finite and covariances (n, dim, dim) SPD."""
    n = len(states)
    assert states.mean.shape == (n, dim), f"{name}.mean has shape {states.mean.shape}"
    assert states.cov.shape == (n, dim, dim), f"{name}.cov has shape {states.cov.shape}"
    assert np.isfinite(states.mean).all(), f"{name}.mean has NaN or inf"
    assert_spd(states.cov, f"{name}.cov")


def assert_valid_estimate(estimate: Estimate, frame: Frame, recording: Recording) -> None:
    """The contract of `Estimator.step`: one belief per present vehicle, finite, SPD."""
    assert isinstance(estimate, Estimate), f"step returned {type(estimate).__name__}"
    vehicles = estimate.vehicles
    assert isinstance(vehicles, StateSet)
    assert sorted(vehicles.ids.tolist()) == sorted(frame.vehicles.tolist()), (
        f"step {frame.k}: estimate has vehicles {vehicles.ids.tolist()}, "
        f"frame has {frame.vehicles.tolist()}"
    )
    assert_state_set(vehicles, recording.setup.vehicle_layout.dim, f"step {frame.k} vehicles")
    if estimate.features is not None:
        assert isinstance(estimate.features, StateSet)
        layout = recording.setup.feature_layout
        dim = layout.dim if layout is not None else estimate.features.mean.shape[1]
        assert_state_set(estimate.features, dim, f"step {frame.k} features")
    if "nis" in estimate.info:  # (Σ NIS, Σ dof) of the step's updates (`types.Estimate`)
        total, dof = estimate.info["nis"]
        assert isinstance(dof, (int, np.integer)) and dof >= 0, f"step {frame.k}: nis dof {dof!r}"
        assert np.isfinite(total) and total >= 0 and (dof > 0 or total == 0), (
            f"step {frame.k}: nis {total!r} with {dof} degrees of freedom")


def _assert_run_valid(estimates: list[Estimate], recording: Recording) -> None:
    assert len(estimates) == len(recording.frames)
    for estimate_k, frame in zip(estimates, recording.frames, strict=True):
        assert_valid_estimate(estimate_k, frame, recording)
        assert isinstance(estimate_k.info, Mapping)


def _assert_same_numbers(a: list[Estimate], b: list[Estimate]) -> None:
    for x, y in zip(a, b, strict=True):
        for part in ("vehicles", "features"):
            sx, sy = getattr(x, part), getattr(y, part)
            assert (sx is None) == (sy is None)
            if sx is not None:
                np.testing.assert_array_equal(sx.ids, sy.ids)
                np.testing.assert_array_equal(sx.mean, sy.mean)
                np.testing.assert_array_equal(sx.cov, sy.cov)


# ----------------------------------------------------------------------------
# the checks
# ----------------------------------------------------------------------------


@functools.lru_cache(maxsize=32)
def _recording(preset: str, seed: int, overrides: tuple[tuple[str, Any], ...]) -> Recording:
    return preset_recording(preset, [seed, 50], dict(overrides))


def on_preset(estimator: type | str, preset: str, overrides: Mapping[str, Any] | None = None) -> type:
    """`estimator` whose contract recordings are runs of `preset` with `overrides` instead of
    its `default_preset`: give it to `check_estimator` or `run_check` to hold the estimator
    to the contract on another scenario (e.g. a short SUMO run). A subclass that changes
    nothing else."""
    cls = _estimator_class(estimator)
    return type(cls.__name__, (cls,), {"default_preset": preset, "__module__": cls.__module__,
                                       "contract_overrides": tuple(sorted((overrides or {}).items()))})


def contract_recording(cls: type, seed: int, **overrides: Any) -> Recording:
    """A short run of the estimator's default preset (or the one `on_preset` chose, with its
    overrides); `CheckSkipped` if an override does not apply to it."""
    overrides = {**dict(getattr(cls, "contract_overrides", ())), **overrides}
    preset = get_preset(cls.default_preset)
    keys = set(preset.params.keys())
    missing = sorted(set(overrides) - keys)
    if missing:
        raise CheckSkipped(f"preset {preset.name!r} has no parameter {missing[0]!r}")
    if "n_steps" in keys:
        overrides.setdefault("n_steps", SMALL_STEPS)
    return _recording(preset.name, seed, tuple(sorted(overrides.items())))


def check_interface(cls: type, seed: int) -> None:
    assert isinstance(cls.name, str) and cls.name, "name must be a non-empty string"
    assert isinstance(cls.summary, str) and cls.summary, f"{cls.name}: summary must be a non-empty string"
    assert isinstance(cls.Params, type) and issubclass(cls.Params, Params), (
        f"{cls.name}: Params must subclass cooploc.params.Params")
    cls.Params()  # defaults are valid
    assert isinstance(cls.needs_truth, bool), f"{cls.name}: needs_truth must be a bool"
    assert cls.default_preset in presets(), f"{cls.name}: unknown preset {cls.default_preset!r}"
    assert callable(cls.step), f"{cls.name}: step must be a method"


def check_valid_estimates(cls: type, seed: int) -> None:
    rec = contract_recording(cls, seed)
    estimates = run_estimator(cls, rec)
    _assert_run_valid(estimates, rec)
    # not a constant: the estimate follows the data
    first, last = estimates[0].vehicles.mean, estimates[-1].vehicles.mean
    assert not np.array_equal(first, last), f"{cls.name}: the estimate does not change"


def check_empty_frames(cls: type, seed: int) -> None:
    # no vehicles at steps 0, 1, 15; no batches at 5–7; empty batches at 10–12
    rec = with_empty_frames(contract_recording(cls, seed))
    assert len(rec.frames[0].vehicles) == 0 and not rec.frames[5].batches
    assert all(len(b) == 0 for b in rec.frames[10].batches.values())
    _assert_run_valid(run_estimator(cls, rec), rec)


def check_same_seed(cls: type, seed: int) -> None:
    rec = contract_recording(cls, seed)
    _assert_same_numbers(run_estimator(cls, rec, seed=7), run_estimator(cls, rec, seed=7))


def check_enter_and_leave(cls: type, seed: int) -> None:
    rec = contract_recording(cls, seed, n_vehicles=3)
    ids = np.sort(rec.truth.vehicle_ids)
    if ids.size < 3:
        raise CheckSkipped("the preset cannot have 3 vehicles")
    # the checks' pattern on the preset's own ids: the second enters at step 5, the
    # third is away for steps 10–19
    absent = {int(ids[i]): steps for i, steps in zip((1, 2), TRAFFIC_ABSENT.values(), strict=True)}
    traffic = with_traffic(rec, absent)
    assert int(ids[1]) not in traffic.frames[4].vehicles
    assert int(ids[2]) not in traffic.frames[15].vehicles
    assert int(ids[2]) in traffic.frames[20].vehicles
    _assert_run_valid(run_estimator(cls, traffic), traffic)


def traffic_recording(seed: Any, n_steps: int = SMALL_STEPS, **overrides: Any) -> Recording:
    """A 3-vehicle ``froehle2018`` run with the `TRAFFIC_ABSENT` pattern."""
    overrides = {"n_vehicles": 3, "n_steps": n_steps, **overrides}
    return with_traffic(preset_recording("froehle2018", seed, overrides), TRAFFIC_ABSENT)


@functools.lru_cache(maxsize=4)
def _froehle_traffic(seed: int) -> Recording:
    return traffic_recording([seed, 2])


def check_froehle_traffic(cls: type, seed: int) -> None:
    if cls.default_preset != "froehle2018":
        raise CheckSkipped("the traffic run is a froehle2018 recording")
    traffic = _froehle_traffic(seed)
    _assert_run_valid(run_estimator(cls, traffic), traffic)


def check_missed_detections_and_clutter(cls: type, seed: int) -> None:
    rec = contract_recording(cls, seed, detection_probability=0.7, clutter_rate=2.0)
    origins = np.concatenate([np.concatenate(list(o.values())) for o in rec.truth.origin])
    assert (origins == -1).any()  # there is clutter to survive
    _assert_run_valid(run_estimator(cls, rec), rec)


def long_run(cls: type, seed: int, n_steps: int = LONG_RUN_STEPS) -> tuple[Recording, Params]:
    """A long, small run of the default preset: two estimated vehicles (anchors on top of
    them where the preset has anchors), one feature and poor GNSS where the preset has
    those parameters; particle estimators capped at `LONG_RUN_PARTICLES`."""
    preset = get_preset(cls.default_preset)
    keys = set(preset.params.keys())
    if "n_steps" not in keys:
        raise CheckSkipped(f"preset {preset.name!r} has no parameter 'n_steps'")
    wanted = {**dict(getattr(cls, "contract_overrides", ())), "n_steps": n_steps,
              "n_vehicles": 2 + int(getattr(preset.params, "n_anchors", 0)),
              "n_features": 1, "gnss_variances": (15.0,)}
    rec = _recording(preset.name, seed, tuple(sorted((k, v) for k, v in wanted.items() if k in keys)))
    return rec, contract_params(cls, LONG_RUN_PARTICLES)


def check_long_run(cls: type, seed: int) -> None:
    rec, params = long_run(cls, seed)
    estimates = run_estimator(cls, rec, params=params)
    _assert_run_valid(estimates, rec)

    def largest_variance(part: str, steps: range) -> float | None:
        sets = [getattr(estimates[k], part) for k in steps]
        return max((np.linalg.eigvalsh(s.cov).max() for s in sets if s is not None and len(s)),
                   default=None)

    half = LONG_RUN_STEPS // 2
    for part in ("vehicles", "features"):
        early = largest_variance(part, range(100, half))
        late = largest_variance(part, range(half, LONG_RUN_STEPS))
        if early is None or late is None:
            continue  # e.g. per-step feature estimates once the vehicles have passed them
        # no drift: the second half is no less certain than the first (factor 2 leaves
        # room for sampling-based covariances), and nothing runs away
        assert late <= 2.0 * early, (part, early, late)
        assert late < 1e4, (part, late)


def check_truth_only_to_references(cls: type, seed: int) -> None:
    signature = inspect.signature(cls).parameters
    received: dict[str, Any] = {}

    class Spy(cls):  # records what the registry's constructor hands over
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            received["args"], received["kwargs"] = args, kwargs
            super().__init__(*args, **kwargs)

    rec = contract_recording(cls, seed)
    estimator = construct(Spy, rec.setup, contract_params(cls), np.random.default_rng(0), truth=rec.truth)
    handed = list(received["args"]) + list(received["kwargs"].values())
    assert not any(isinstance(x, Truth) for x in handed), "the full Truth was handed over"
    assert not any(isinstance(x, Truth) for x in vars(estimator).values())
    if cls.needs_truth:
        assert "truth" in signature and signature["truth"].kind is inspect.Parameter.KEYWORD_ONLY
        assert set(received["kwargs"]) == {"truth"}
        assert isinstance(received["kwargs"]["truth"], AssociationTruth)
    else:
        # it cannot even accept truth
        assert "truth" not in signature
        assert not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in signature.values())
        assert received["kwargs"] == {}
        assert not any(isinstance(x, AssociationTruth) for x in handed)


def check_true_states_never_read(cls: type, seed: int) -> None:
    rec = contract_recording(cls, seed)
    heading = rec.truth.vehicle_heading
    garbage = dataclasses.replace(
        rec.truth, vehicle_states=np.full_like(rec.truth.vehicle_states, 123.0),
        feature_states=np.full_like(rec.truth.feature_states, -7.0),
        vehicle_heading=None if heading is None else np.full_like(heading, 0.5))
    blind = Recording(rec.setup, rec.frames, garbage)
    _assert_same_numbers(run_estimator(cls, rec, seed=3), run_estimator(cls, blind, seed=3))


@functools.lru_cache(maxsize=2)
def sumo_traffic(seed: int) -> Recording:
    """A tiny SUMO run (`cooploc.scenarios.sumo.TINY_GRID`), simulated with a cache of its
    own; `CheckSkipped` without the ``sumo`` extra."""
    import tempfile

    from cooploc.scenarios.sumo import TINY_GRID, SumoNotInstalledError

    preset = get_preset("sumo-grid-tlr")
    previous = os.environ.get("COOPLOC_CACHE_DIR")
    with tempfile.TemporaryDirectory(prefix="cooploc-contract-") as cache:
        os.environ["COOPLOC_CACHE_DIR"] = cache  # the user's cache stays untouched
        try:
            return preset.generate(np.random.default_rng([seed, 51]),
                                   preset.params.with_overrides(TINY_GRID))
        except SumoNotInstalledError as exc:
            raise CheckSkipped(str(exc)) from None
        finally:
            if previous is None:
                os.environ.pop("COOPLOC_CACHE_DIR", None)
            else:
                os.environ["COOPLOC_CACHE_DIR"] = previous


def check_sumo_traffic(cls: type, seed: int) -> None:
    traffic = sumo_traffic(seed)
    present = traffic.truth.vehicle_present
    assert (~present[0] & present.any(axis=0)).any(), "no vehicle enters"
    assert (present[0] & ~present[-1]).any(), "no vehicle leaves"
    missing = [k for k in getattr(cls, "required_sensors", ()) if k not in traffic.setup.sensors]
    if missing:  # a method that needs a sensor SUMO traffic does not have must say so clearly
        try:
            run_estimator(cls, traffic)
        except ConfigError as exc:
            wanted = f"{cls.name} needs the measurement kinds {missing[0]}"
            assert wanted in str(exc), f"unclear refusal: {exc}"
            return
        raise AssertionError(f"{cls.name} ran without its sensors {missing} instead of refusing")
    try:
        estimates = run_estimator(cls, traffic)
    except ConfigError as exc:
        # the kinds are there but not in the form the method models (e.g. a heading in the
        # state, GNSS rows of the position only): a clear refusal names what it needs
        if f"{cls.name} needs " in str(exc):
            return
        raise
    _assert_run_valid(estimates, traffic)


@dataclass(frozen=True)
class Check:
    """One contract check: `function(cls, seed)`; `slow` checks take tens of seconds."""

    function: Callable[[type, int], None]
    slow: bool = False


CHECKS: dict[str, Check] = {
    "interface": Check(check_interface),
    "valid_estimates": Check(check_valid_estimates),
    "empty_frames": Check(check_empty_frames),
    "same_seed": Check(check_same_seed),
    "enter_and_leave": Check(check_enter_and_leave),
    "froehle_traffic": Check(check_froehle_traffic),
    "missed_detections_and_clutter": Check(check_missed_detections_and_clutter),
    "long_run": Check(check_long_run, slow=True),
    "truth_only_to_references": Check(check_truth_only_to_references),
    "true_states_never_read": Check(check_true_states_never_read),
    "sumo_traffic": Check(check_sumo_traffic),
}


def run_check(estimator: type | str, check: str, seed: int = 0) -> None:
    """Run contract check `check` (a key of `CHECKS`) on an estimator class or registered
    name; AssertionError if it fails, `CheckSkipped` if it does not apply."""
    if check not in CHECKS:
        raise ConfigError(f"unknown check {check!r}; known: {', '.join(CHECKS)}")
    CHECKS[check].function(_estimator_class(estimator), seed)


def check_estimator(estimator: type | str, *, seed: int = 0, slow: bool = True) -> dict[str, str]:
    """Run the whole contract on an estimator class (registered or not) or registered name.

    Returns {check: "passed" or "skipped: why"}; the first failing check raises an
    `AssertionError` whose message starts with the check's name. `slow=False` leaves out
    the long-run check.
    """
    cls = _estimator_class(estimator)
    outcome: dict[str, str] = {}
    for name, check in CHECKS.items():
        if check.slow and not slow:
            continue
        try:
            check.function(cls, seed)
        except CheckSkipped as exc:
            outcome[name] = f"skipped: {exc}"
        except AssertionError as exc:
            raise AssertionError(f"{name}: {getattr(cls, 'name', cls)!s} fails the contract: {exc}") from exc
        else:
            outcome[name] = "passed"
    return outcome
