"""The estimator contract (STYLE §9): every registered estimator, present and future.

Parametrised over `cooploc.estimators.estimators()`, so a newly registered estimator
is covered without touching this file. Each runs on a short recording of its own
`default_preset` (``froehle2018`` for the Fröhle-type methods) and must

- declare the interface (`name`, `summary`, `Params`, `needs_truth`, `default_preset`);
- return a valid `Estimate` every step: one belief per present vehicle (ids equal to
  `frame.vehicles` as a set), mean (n, dx), no NaN, covariances SPD;
- survive empty frames: no vehicles, vehicles but no batches, empty batches;
- give identical numbers for the same seed;
- follow vehicles that enter and leave (traffic);
- survive missed detections and clutter;
- stay finite with bounded covariance over a long run (2000 steps of a small version of
  the default preset, particle counts capped);
- never see truth unless it is a known-association reference (`needs_truth`), which
  receives an `AssociationTruth` (association only, no states);
- follow real traffic: a tiny SUMO run (`cooploc.scenarios.sumo.TINY_GRID`) where
  vehicles and pedestrians enter and leave, with zone-dependent GNSS covariances.

Scenario-specific variants (traffic needs ≥ 3 vehicles, clutter needs the scenario's
`detection_probability` / `clutter_rate`) are skipped, with the reason, for presets
that cannot express them.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.estimators import estimators, get_estimator, make_estimator
from cooploc.estimators.base import AssociationTruth
from cooploc.params import Params
from cooploc.scenarios import get_preset, presets
from cooploc.types import Estimate, Recording, Truth
from helpers import (
    SMALL_STEPS,
    TRAFFIC_ABSENT,
    assert_valid_estimate,
    preset_recording,
    run_estimator,
    with_empty_frames,
    with_traffic,
)

NAMES = sorted(estimators())
# the registry module itself (the package `cooploc` re-exports a function of that name)
registry = importlib.import_module("cooploc.estimators")


@functools.lru_cache(maxsize=32)
def _recording(preset: str, seed: int, overrides: tuple[tuple[str, Any], ...]) -> Recording:
    return preset_recording(preset, [seed, 50], dict(overrides))


def contract_recording(name: str, seed: int, **overrides: Any) -> Recording:
    """A short run of the estimator's default preset; skip if an override does not apply."""
    preset = get_preset(get_estimator(name).default_preset)
    keys = set(preset.params.keys())
    missing = sorted(set(overrides) - keys)
    if missing:
        pytest.skip(f"preset {preset.name!r} has no parameter {missing[0]!r}")
    if "n_steps" in keys:
        overrides.setdefault("n_steps", SMALL_STEPS)
    return _recording(preset.name, seed, tuple(sorted(overrides.items())))


def assert_run_valid(estimates: list[Estimate], recording: Recording) -> None:
    assert len(estimates) == len(recording.frames)
    for estimate, frame in zip(estimates, recording.frames, strict=True):
        assert_valid_estimate(estimate, frame, recording)
        assert isinstance(estimate.info, Mapping)


def assert_same_numbers(a: list[Estimate], b: list[Estimate]) -> None:
    for x, y in zip(a, b, strict=True):
        for part in ("vehicles", "features"):
            sx, sy = getattr(x, part), getattr(y, part)
            assert (sx is None) == (sy is None)
            if sx is not None:
                np.testing.assert_array_equal(sx.ids, sy.ids)
                np.testing.assert_array_equal(sx.mean, sy.mean)
                np.testing.assert_array_equal(sx.cov, sy.cov)


# ----------------------------------------------------------------------------
# interface
# ----------------------------------------------------------------------------


def test_registry_is_not_empty() -> None:
    assert {"gnss-kf", "oracle-kf"} <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_declares_the_interface(name: str) -> None:
    cls = get_estimator(name)
    assert cls.name == name
    assert isinstance(cls.summary, str) and cls.summary
    assert issubclass(cls.Params, Params)
    cls.Params()  # defaults are valid
    assert isinstance(cls.needs_truth, bool)
    assert cls.default_preset in presets(), f"{name}: unknown preset {cls.default_preset!r}"
    assert callable(cls.step)


# ----------------------------------------------------------------------------
# estimates
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_valid_estimates(name: str, seed: int) -> None:
    rec = contract_recording(name, seed)
    estimates = run_estimator(name, rec)
    assert_run_valid(estimates, rec)
    # not a constant: the estimate follows the data
    first, last = estimates[0].vehicles.mean, estimates[-1].vehicles.mean
    assert not np.array_equal(first, last)


@pytest.mark.parametrize("name", NAMES)
def test_empty_frames_survive(name: str, seed: int) -> None:
    # no vehicles at steps 0, 1, 15; no batches at 5–7; empty batches at 10–12
    rec = with_empty_frames(contract_recording(name, seed))
    assert len(rec.frames[0].vehicles) == 0 and not rec.frames[5].batches
    assert all(len(b) == 0 for b in rec.frames[10].batches.values())
    assert_run_valid(run_estimator(name, rec), rec)


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_numbers(name: str, seed: int) -> None:
    rec = contract_recording(name, seed)
    assert_same_numbers(run_estimator(name, rec, seed=7), run_estimator(name, rec, seed=7))


@pytest.mark.parametrize("name", NAMES)
def test_vehicles_enter_and_leave(name: str, seed: int) -> None:
    rec = contract_recording(name, seed, n_vehicles=3)
    ids = np.sort(rec.truth.vehicle_ids)
    if ids.size < 3:
        pytest.skip("the preset cannot have 3 vehicles")
    # the suite's pattern on the preset's own ids: the second enters at step 5, the
    # third is away for steps 10–19
    absent = {int(ids[i]): steps for i, steps in zip((1, 2), TRAFFIC_ABSENT.values(),
                                                      strict=True)}
    traffic = with_traffic(rec, absent)
    assert int(ids[1]) not in traffic.frames[4].vehicles
    assert int(ids[2]) not in traffic.frames[15].vehicles
    assert int(ids[2]) in traffic.frames[20].vehicles
    assert_run_valid(run_estimator(name, traffic), traffic)


@pytest.mark.parametrize("name", NAMES)
def test_traffic_fixture(name: str, traffic: Recording) -> None:
    if get_estimator(name).default_preset != "froehle2018":
        pytest.skip("the traffic fixture is a froehle2018 recording")
    assert_run_valid(run_estimator(name, traffic), traffic)


@pytest.mark.parametrize("name", NAMES)
def test_missed_detections_and_clutter(name: str, seed: int) -> None:
    rec = contract_recording(name, seed, detection_probability=0.7, clutter_rate=2.0)
    origins = np.concatenate([np.concatenate(list(o.values())) for o in rec.truth.origin])
    assert (origins == -1).any()  # there is clutter to survive
    assert_run_valid(run_estimator(name, rec), rec)


#: long runs check stability, not accuracy: fewer particles make degeneracy likelier
LONG_RUN_PARTICLES = 300


def long_run(name: str, seed: int, n_steps: int) -> tuple[Recording, Params]:
    """A long, small run of the default preset: two estimated vehicles (anchors on top of
    them where the preset has anchors), one feature and poor GNSS where the preset has
    those parameters; particle estimators capped at `LONG_RUN_PARTICLES`."""
    cls = get_estimator(name)
    preset = get_preset(cls.default_preset)
    keys = set(preset.params.keys())
    if "n_steps" not in keys:
        pytest.skip(f"preset {preset.name!r} has no parameter 'n_steps'")
    wanted = {"n_steps": n_steps, "n_vehicles": 2 + int(getattr(preset.params, "n_anchors", 0)),
              "n_features": 1, "gnss_variances": (15.0,)}
    rec = _recording(preset.name, seed, tuple(sorted((k, v) for k, v in wanted.items() if k in keys)))
    params = cls.Params()
    if "n_particles" in params.keys():
        params = params.with_overrides(
            {"n_particles": min(params.n_particles, LONG_RUN_PARTICLES)})  # type: ignore[attr-defined]
    return rec, params


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_long_run_stays_finite_and_bounded(name: str, seed: int) -> None:
    rec, params = long_run(name, seed, n_steps=2000)
    estimates = run_estimator(name, rec, params=params)
    assert_run_valid(estimates, rec)

    def largest_variance(part: str, steps: range) -> float | None:
        sets = [getattr(estimates[k], part) for k in steps]
        return max((np.linalg.eigvalsh(s.cov).max() for s in sets if s is not None and len(s)),
                   default=None)

    for part in ("vehicles", "features"):
        early = largest_variance(part, range(100, 1000))
        late = largest_variance(part, range(1000, 2000))
        if early is None or late is None:
            continue  # e.g. per-step feature estimates once the vehicles have passed them
        # no drift: the second half is no less certain than the first (factor 2 leaves
        # room for sampling-based covariances), and nothing runs away
        assert late <= 2.0 * early, (part, early, late)
        assert late < 1e4, (part, late)


# ----------------------------------------------------------------------------
# truth
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_truth_is_passed_only_to_references(name: str, seed: int,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    cls = get_estimator(name)
    params = inspect.signature(cls).parameters
    received: dict[str, Any] = {}

    class Spy(cls):  # records what make_estimator hands the constructor
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            received["args"], received["kwargs"] = args, kwargs
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(registry, "get_estimator", lambda _: Spy)
    rec = contract_recording(name, seed)
    estimator = make_estimator(name, rec.setup, None, np.random.default_rng(0), truth=rec.truth)
    handed = list(received["args"]) + list(received["kwargs"].values())
    assert not any(isinstance(x, Truth) for x in handed), "the full Truth was handed over"
    assert not any(isinstance(x, Truth) for x in vars(estimator).values())
    if cls.needs_truth:
        assert "truth" in params and params["truth"].kind is inspect.Parameter.KEYWORD_ONLY
        assert set(received["kwargs"]) == {"truth"}
        assert isinstance(received["kwargs"]["truth"], AssociationTruth)
    else:
        # it cannot even accept truth
        assert "truth" not in params
        assert not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
        assert received["kwargs"] == {}
        assert not any(isinstance(x, AssociationTruth) for x in handed)


@pytest.mark.parametrize("name", NAMES)
def test_true_states_are_never_read(name: str, seed: int) -> None:
    rec = contract_recording(name, seed)
    garbage = dataclasses.replace(
        rec.truth, vehicle_states=np.full_like(rec.truth.vehicle_states, 123.0),
        feature_states=np.full_like(rec.truth.feature_states, -7.0))
    blind = Recording(rec.setup, rec.frames, garbage)
    assert_same_numbers(run_estimator(name, rec, seed=3), run_estimator(name, blind, seed=3))


# ----------------------------------------------------------------------------
# SUMO traffic
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sumo_traffic(seed: int, tmp_path_factory: pytest.TempPathFactory) -> Recording:
    """A tiny SUMO run (cache in a temporary folder, not the user's)."""
    from cooploc.scenarios import sumo

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("COOPLOC_CACHE_DIR", str(tmp_path_factory.mktemp("sumo-cache")))
        params = get_preset("sumo-grid-tlr").params.with_overrides(sumo.TINY_GRID)
        return sumo.generate(params, np.random.default_rng([seed, 51]))


@pytest.mark.parametrize("name", NAMES)
def test_sumo_traffic(name: str, sumo_traffic: Recording) -> None:
    present = sumo_traffic.truth.vehicle_present
    assert (~present[0] & present.any(axis=0)).any(), "no vehicle enters"
    assert (present[0] & ~present[-1]).any(), "no vehicle leaves"
    missing = [k for k in getattr(get_estimator(name), "required_sensors", ())
               if k not in sumo_traffic.setup.sensors]
    if missing:  # a method that needs a sensor SUMO traffic does not have must say so clearly
        with pytest.raises(ConfigError, match=f"{name} needs the measurement kinds {missing[0]}"):
            run_estimator(name, sumo_traffic)
        return
    assert_run_valid(run_estimator(name, sumo_traffic), sumo_traffic)
