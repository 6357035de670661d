"""Shared fixtures of the test suite.

Randomness: every test draws from generators seeded from one suite seed, 20240611 by
default. ``pytest --seed N`` (or ``COOPLOC_TEST_SEED=N``) runs the whole suite with
another one; the tests are written to pass for any seed (their tolerances are set
for a failure probability below ~1e-6 per check), so no seed is cherry-picked.

Slow tests (Monte Carlo over full-length runs) are marked ``@pytest.mark.slow`` and
run by default; ``pytest -m "not slow"`` skips them.

Helpers that tests import (recording surgery, contract checks) live in
``tests/helpers.py``.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))  # make `helpers` importable

from cooploc.types import Recording
from helpers import froehle_recording, traffic_recording

DEFAULT_SEED = 20240611


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--seed", action="store", type=int, default=None,
        help="suite seed for every random test (default: $COOPLOC_TEST_SEED or 20240611)",
    )


def _suite_seed(config: pytest.Config) -> int:
    option = config.getoption("--seed")
    if option is not None:
        return int(option)
    return int(os.environ.get("COOPLOC_TEST_SEED", DEFAULT_SEED))


def pytest_report_header(config: pytest.Config) -> str:
    return f"cooploc suite seed: {_suite_seed(config)} (change with --seed N)"


@pytest.fixture(scope="session")
def seed(pytestconfig: pytest.Config) -> int:
    """The suite seed (see module docstring)."""
    return _suite_seed(pytestconfig)


@pytest.fixture
def rng(seed: int, request: pytest.FixtureRequest) -> np.random.Generator:
    """A generator for one test: the suite seed mixed with the test's name, so that tests
    do not share draws, yet each test is reproducible for a given suite seed."""
    digest = hashlib.sha256(request.node.nodeid.encode()).digest()
    return np.random.default_rng([seed, int.from_bytes(digest[:8], "little")])


@pytest.fixture(scope="session")
def froehle_small(seed: int) -> Recording:
    """A short (`helpers.SMALL_STEPS` = 40 steps) run of the ``froehle2018`` preset."""
    return froehle_recording([seed, 1])


@pytest.fixture(scope="session")
def traffic(seed: int) -> Recording:
    """3 vehicles: vehicle 1 enters at step 5, vehicle 2 is away for steps 10–19."""
    return traffic_recording([seed, 2])


@pytest.fixture(scope="module")
def sumo_cache(tmp_path_factory: pytest.TempPathFactory):
    """A SUMO cache folder of the test module's own (``COOPLOC_CACHE_DIR`` pointed at it),
    so that SUMO tests neither read nor fill the user's cache."""
    folder = tmp_path_factory.mktemp("sumo-cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("COOPLOC_CACHE_DIR", str(folder))
        yield folder / "sumo"
