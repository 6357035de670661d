"""The fuzz suite of saved recordings (issue 16, item 9): nothing escapes but `CooplocError`.

For every preset family (`fuzz_recordings.FAMILIES`), hand-made corruptions and
hypothesis-chosen structural and semantic mutations of a saved recording are loaded and
run through every estimator that accepts them. Allowed outcomes: refused with a
`CooplocError` (at load or construction), an `EstimatorError`/`CooplocError` from a step,
or finite estimates. Not allowed: any other exception, or NaN/inf in an estimate without
an error. Hypothesis is derandomized with bounded examples, so CI time is bounded and
every run tries the same cases; `tests/fuzz_recordings.py` prints the counts.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fuzz_recordings import FAILURES, FAMILIES, HAND, family_recording, mutate

FAST_FAMILIES = [f for f in sorted(FAMILIES) if f != "sumo"]
EXAMPLES = 6    # random mutations per family and kind (hypothesis examples)
FUZZ = settings(derandomize=True, max_examples=EXAMPLES, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def saved(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One saved recording per family, made once (the SUMO one on the tiny grid)."""
    return _Saved(tmp_path_factory.mktemp("fuzz"))  # made lazily: unused families cost nothing


class _Saved(dict):
    def __init__(self, root: Path) -> None:
        super().__init__()
        self.root = root

    def __missing__(self, family: str) -> Path:
        self[family] = family_recording(family, self.root / family / "base")
        return self[family]


def run(saved: dict[str, Path], family: str, kind: str, seed: int | str) -> None:
    what, outcomes = mutate(saved[family], saved.root / family / f"case-{kind}", family, kind, seed)
    bad = [(name, outcome, detail) for name, outcome, detail in outcomes if outcome in FAILURES]
    assert not bad, f"mutation {what!r}: {bad}"


#: the hand-made corruptions run on every family; two families (GNSS + V2F, GNSS +
#: odometry + radar) in the fast tier, the others marked slow (they still run in CI)
HAND_FAST = {"froehle2018", "gulati"}


def hand_cases() -> list:
    return [pytest.param(family, corruption, id=f"{family}-{corruption}",
                         marks=[] if family in HAND_FAST else [pytest.mark.slow])
            for family in FAST_FAMILIES for corruption in sorted(HAND)]


@pytest.mark.parametrize(("family", "corruption"), hand_cases())
def test_hand_made_corruptions(saved: dict[str, Path], family: str, corruption: str) -> None:
    run(saved, family, "hand", corruption)


@pytest.mark.parametrize("family", FAST_FAMILIES)
@pytest.mark.parametrize("kind", ["structural", "semantic"])
@FUZZ
@given(seed=st.integers(0, 2**31 - 1))
def test_random_mutations(saved: dict[str, Path], family: str, kind: str, seed: int) -> None:
    run(saved, family, kind, seed)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["hand", "structural", "semantic"])
def test_sumo_tiny_grid(saved: dict[str, Path], kind: str, tmp_path: Path,
                        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path / "cache"))
    failed = []
    for seed in sorted(HAND) if kind == "hand" else range(EXAMPLES):
        what, outcomes = mutate(saved["sumo"], saved.root / "sumo" / f"case-{kind}", "sumo", kind, seed)
        failed += [(what, name, outcome, detail) for name, outcome, detail in outcomes
                   if outcome in FAILURES]
    assert not failed, failed
