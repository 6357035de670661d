"""Frames made on demand (`cooploc.streams`): the same numbers as a list of frames, passes
that start again from the same generator states, and memory that does not grow with
the horizon."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import cooploc.streams as streams
from cooploc.errors import InvalidInputError
from cooploc.metrics import evaluate, score_association
from cooploc.scenarios import get_preset
from cooploc.types import Batch, Frame, Recording
from helpers import run_estimator


def _generate(name: str, lazy: bool, monkeypatch: pytest.MonkeyPatch, **overrides: object) -> Recording:
    with monkeypatch.context() as patch:
        patch.setattr(streams, "STREAM_FROM_STEPS", 0 if lazy else 10**9)
        preset = get_preset(name)
        return preset.generate(np.random.default_rng(5), preset.params.with_overrides(overrides))


def _assert_same_frames(a: Recording, b: Recording) -> None:
    assert len(a.frames) == len(b.frames)
    for k, (fa, fb) in enumerate(zip(a.frames, b.frames, strict=True)):
        assert fa.k == fb.k == k and fa.t == fb.t
        np.testing.assert_array_equal(fa.vehicles, fb.vehicles)
        np.testing.assert_array_equal(fa.links, fb.links)
        assert set(fa.batches) == set(fb.batches)
        for kind in fa.batches:
            for field in ("z", "cov", "sensor", "subject"):
                np.testing.assert_array_equal(getattr(fa.batches[kind], field),
                                              getattr(fb.batches[kind], field))
            np.testing.assert_array_equal(a.truth.origin[k][kind], b.truth.origin[k][kind])


@pytest.mark.parametrize(("name", "overrides"), [
    ("brambilla-crossroad", {"clutter_rate": 1.0, "detection_probability": 0.8, "n_steps": 8}),
    ("sumo-grid-tlr", {"duration": 6.0, "warmup": 30.0}),
])
def test_a_stream_gives_the_frames_of_the_list_bit_for_bit(name: str, overrides: dict,
                                                           monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path))
    eager = _generate(name, False, monkeypatch, **overrides)
    lazy = _generate(name, True, monkeypatch, **overrides)
    assert isinstance(lazy.frames, streams.LazyFrames) and isinstance(eager.frames, tuple)
    _assert_same_frames(eager, lazy)
    _assert_same_frames(eager, lazy)  # a second pass starts again from the same generator states
    np.testing.assert_array_equal(lazy.frames[-1].links, eager.frames[-1].links)
    assert [f.k for f in lazy.frames[2:5]] == [2, 3, 4]
    # an estimator that reads the association (oracle-kf) and one that does not: the same numbers
    for estimator in ("gnss-kf", "oracle-kf"):
        pairs = zip(run_estimator(estimator, eager), run_estimator(estimator, lazy), strict=True)
        for e_eager, e_lazy in pairs:
            np.testing.assert_array_equal(e_eager.vehicles.mean, e_lazy.vehicles.mean)
            np.testing.assert_array_equal(e_eager.vehicles.cov, e_lazy.vehicles.cov)


def test_origins_are_kept_and_going_back_starts_again(monkeypatch: pytest.MonkeyPatch) -> None:
    lazy = _generate("brambilla-crossroad", True, monkeypatch)
    stream = lazy.frames.stream
    for _ in lazy.frames:
        pass
    assert stream.passes == 1
    for k in range(len(lazy.frames)):   # the origins of a finished pass make no frame again
        lazy.truth.origin[k]
    assert stream.passes == 1
    # the runner's scoring after an estimator's pass makes no frame again either
    estimates = run_estimator("gnss-kf", lazy)   # a pass of its own (from step 0)
    errors = evaluate(lazy, estimates)
    score_association(lazy, estimates)
    assert stream.passes == 2 and len(errors)
    lazy.frames[3]                      # going back does
    assert stream.passes == 3
    with pytest.raises(IndexError):
        lazy.frames[len(lazy.frames)]


def _frame(k: int, rows: int = 1) -> Frame:
    ids = np.zeros(rows, dtype=np.int64)
    batch = Batch(np.zeros((rows, 2)), np.tile(np.eye(2), (rows, 1, 1)), ids, ids)
    return Frame(k, float(k), np.array([0]), {"gnss": batch})


def test_a_stream_checks_each_step_as_it_is_made() -> None:
    def wrong_step():
        yield _frame(0), {"gnss": np.array([0])}
        yield _frame(5), {"gnss": np.array([0])}

    frames = streams.LazyFrames(streams.FrameStream(2, wrong_step))
    with pytest.raises(InvalidInputError, match=r"frames\[1\]\.k must be 1"):
        list(frames)

    def short_origin():
        yield _frame(0, rows=2), {"gnss": np.array([0])}

    with pytest.raises(InvalidInputError, match=r"origin\[0\]\['gnss'\] must have 2 rows"):
        streams.LazyFrames(streams.FrameStream(1, short_origin))[0]


def test_a_pass_over_a_stream_holds_one_frame_not_all(monkeypatch: pytest.MonkeyPatch) -> None:
    def traced(fn) -> int:
        tracemalloc.start()
        fn()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return peak

    settings = {"n_steps": 40}
    lazy = _generate("brambilla-crossroad", True, monkeypatch, **settings)
    eager_frames = traced(lambda: _generate("brambilla-crossroad", False, monkeypatch, **settings).frames)
    one_pass = traced(lambda: [None for _ in lazy.frames])
    # making the list holds every frame at once; a pass one at a time (plus the compact origins)
    assert one_pass < eager_frames / 4, (one_pass, eager_frames)
