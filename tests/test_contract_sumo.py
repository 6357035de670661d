"""The estimator contract on a short SUMO recording (issue 14): every registered estimator.

`tests/test_contract.py` holds each estimator to the contract on its own default
preset; here `cooploc.testing.check_estimator` runs the same checks (through `on_preset`) on the
tiny generated SUMO grid (`cooploc.scenarios.sumo.TINY_GRID`, 15 s of traffic: vehicles
and pedestrians enter and leave, features appear and disappear). An estimator
that can use nothing such a recording offers must instead be refused by
`registry.construct` with a `ConfigError` that says so: "needs the measurement kinds …"
when a required sensor is missing, "can use nothing this scenario offers" when none of
the sensors is one it reads, or the estimator's own "needs …" when the sensors are
there but not in the form it models.

Three checks cannot apply to SUMO recordings and skip with their reason:
``enter_and_leave`` edits a preset's ``n_vehicles`` (SUMO traffic enters and leaves by
itself), ``froehle_traffic`` is a froehle2018 run, and ``long_run`` (slow, left out)
needs ``n_steps``. The SUMO traffic is simulated once per worker into a temporary cache.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.registry import construct, estimators, get_estimator
from cooploc.scenarios.sumo import TINY_GRID
from cooploc.testing import check_estimator, contract_recording, on_preset
from cooploc.types import Recording

pytest.importorskip("sumolib", reason="the sumo extra is not installed")

PRESET = "sumo-grid-tlr"
#: the tiny grid for 15 s (20 frames: `with_empty_frames` edits frames up to 15)
SUMO = {**TINY_GRID, "duration": 15.0}
#: the checks that must pass on the SUMO recording (the others skip: see the docstring)
RUN_HERE = ("interface", "valid_estimates", "empty_frames", "same_seed", "missed_detections_and_clutter",
            "truth_only_to_references", "true_states_never_read", "sumo_traffic")
#: particle estimators, slow per step on city traffic
SLOW = {"icp-da-pf", "rsu-bp"}


@pytest.fixture(scope="module", autouse=True)
def _cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    folder = tmp_path_factory.mktemp("sumo-contract-cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("COOPLOC_CACHE_DIR", str(folder))
        yield folder


def _sumo_estimator(name: str) -> type:
    return on_preset(name, PRESET, SUMO)


def _recording(seed: int) -> Recording:
    """The SUMO recording the checks use (cached by `cooploc.testing`)."""
    return contract_recording(_sumo_estimator("gnss-kf"), seed)


def _refusal(name: str, rec: Recording) -> str | None:
    """`construct`'s refusal of `name` on the SUMO recording, or None if it is accepted."""
    cls = get_estimator(name)
    try:
        construct(cls, rec.setup, None, np.random.default_rng(0), truth=rec.truth)
    except ConfigError as exc:
        return str(exc)
    return None


NAMES = sorted(estimators())


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in NAMES])
def test_contract_on_sumo(name: str, seed: int) -> None:
    """The whole contract where `construct` accepts the SUMO recording; where it refuses,
    the refusal names what is missing."""
    rec = _recording(seed)
    refused = _refusal(name, rec)
    if refused is None:
        outcome = check_estimator(_sumo_estimator(name), seed=seed, slow=False)
        assert all(outcome[c] == "passed" for c in RUN_HERE), outcome
        return
    missing = [k for k in getattr(get_estimator(name), "required_sensors", ()) if k not in rec.setup.sensors]
    if missing:
        assert f"{name} needs the measurement kinds {', '.join(missing)}" in refused, refused
    else:
        own = f"{name} needs "  # the estimator's own refusal: the sensors are there, not in its form
        assert f"{name} can use nothing this scenario offers" in refused or own in refused, refused


def test_most_estimators_run_on_sumo(seed: int) -> None:
    """The SUMO contract is not vacuous: the GNSS baseline, the bound and the V2F methods run."""
    rec = _recording(seed)
    for name in ("gnss-kf", "oracle-kf", "icp", "icp-da-lc", "icp-da-pf", "rsu-bp", "oracle-pose", "plbp",
                 "prior-lbp"):
        assert _refusal(name, rec) is None, name
