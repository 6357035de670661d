"""Frames made on demand: a recording whose memory does not grow with its horizon.

A scenario generator that draws its measurements step by step (each step from the
generators' state after the previous one) can hand its `Recording` a `FrameStream`
instead of a list of frames: a restartable producer of (frame, origin) per step. The
recording's `frames` and its truth's `origin` are then views of the stream
(`LazyFrames`, `LazyOrigins`) that make each step when it is asked for:

- the frame of step k is kept until another step is asked for (an estimator's `step`
  and a known-association reference reading `truth.origin[k]` meet the same one); going
  back to an earlier step starts the producer again from its saved generator states,
  so every pass sees the same numbers, bit for bit;
- what is compact is kept once made: the time of each step (`Recording.time_of`) and
  the origin of every row (the truth metrics need, a few bytes per measurement), so
  that scoring a run after stepping through it makes no frame again;
- the checks `Recording` makes of a list of frames (step index, origins aligned with
  the rows) are made on each step as it is produced.

A pass over the frames costs what generating them costs; what the stream saves is the
memory of every frame at once (measurements, covariances, links). So scenarios stream
only long runs (`is_long`: more than `STREAM_FROM_STEPS` steps), where the frames would
dominate memory, and make short ones at once, where passing over them again would cost
time for nothing; the numbers are the same either way.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.types import Frame, IntArray

__all__ = ["STREAM_FROM_STEPS", "FrameStream", "LazyFrames", "LazyOrigins", "Step", "is_long", "streamed"]

Step = tuple[Frame, Mapping[str, IntArray]]

#: runs of more steps than this make their frames on demand
STREAM_FROM_STEPS = 1000


def is_long(n_steps: int) -> bool:
    """Whether a run of `n_steps` steps should stream its frames."""
    return n_steps > STREAM_FROM_STEPS


class FrameStream:
    """Steps 0 … n_steps − 1 of a recording, made by `start()` on demand.

    Parameters
    ----------
    n_steps : number of steps.
    start : returns a fresh iterator of (frame, origin) for steps 0, 1, …; every call
        must give the same steps (restore the generators' states inside it).
    """

    def __init__(self, n_steps: int, start: Callable[[], Iterator[Step]]) -> None:
        self.n_steps = int(n_steps)
        self._start = start
        self._producer: Iterator[Step] | None = None
        self._at = -1                      # the step `_current` holds
        self._current: Step | None = None
        self._origins: list[Mapping[str, IntArray]] = []   # kept once made: compact
        self._times: list[float] = []
        self.passes = 0                    # how often the producer was (re)started

    def step(self, k: int) -> Step:
        """(frame, origin) of step k."""
        if not 0 <= k < self.n_steps:
            raise IndexError(f"step {k} of a stream of {self.n_steps} steps")
        if k == self._at and self._current is not None:
            return self._current
        if self._producer is None or k < self._at:
            self._producer, self._at = self._start(), -1
            self.passes += 1
        while self._at < k:
            self._current = self._made(self._at + 1, next(self._producer))
            self._at += 1
        assert self._current is not None
        return self._current

    def time(self, k: int) -> float:
        """The time (s) of step k (made once, then kept)."""
        if k >= len(self._times):
            self.step(k)
        return self._times[k]

    def origin(self, k: int) -> Mapping[str, IntArray]:
        """The origins of step k's rows (made once, then kept)."""
        if k >= len(self._origins):
            self.step(k)
        return self._origins[k]

    def _made(self, k: int, made: Step) -> Step:
        frame, origin = made
        if frame.k != k:
            raise InvalidInputError(f"Recording.frames[{k}].k must be {k}, got {frame.k}")
        for kind, batch in frame.batches.items():
            rows = origin.get(kind)
            if rows is None or np.asarray(rows).size != len(batch):
                raise InvalidInputError(
                    f"Recording.truth.origin[{k}][{kind!r}] must have {len(batch)} rows, "
                    f"got {None if rows is None else np.asarray(rows).size}")
        if k == len(self._origins):
            self._origins.append(origin)
            self._times.append(frame.t)
        return made


class _View(Sequence):
    """A read-only sequence over the steps of a stream (`is_stream`: `types` keeps it lazy)."""

    is_stream = True

    def __init__(self, stream: FrameStream) -> None:
        self.stream = stream

    def __len__(self) -> int:
        return self.stream.n_steps

    def _item(self, k: int) -> Any:
        raise NotImplementedError

    def __getitem__(self, k: Any) -> Any:
        """Item k (negative counts from the end), or a list for a slice."""
        if isinstance(k, slice):
            return [self._item(i) for i in range(*k.indices(len(self)))]
        k = int(k)
        if k < 0:
            k += len(self)
        return self._item(k)

    def __iter__(self) -> Iterator[Any]:
        return (self._item(k) for k in range(len(self)))


class LazyFrames(_View):
    """`Recording.frames` of a stream: frame k made when asked for."""

    def _item(self, k: int) -> Frame:
        return self.stream.step(k)[0]

    def time(self, k: int) -> float:
        """The time (s) of frame k, without making it again once it was made."""
        return self.stream.time(k)


class LazyOrigins(_View):
    """`Truth.origin` of a stream: the origins of step k, made with its frame and kept."""

    def _item(self, k: int) -> Mapping[str, IntArray]:
        return self.stream.origin(k)


def streamed(n_steps: int, start: Callable[[], Iterator[Step]], lazy: bool
             ) -> tuple[Sequence[Frame], Sequence[Mapping[str, IntArray]]]:
    """(frames, origins) for `Recording` and `Truth`: views of a `FrameStream` if `lazy`,
    else every step made now (lists)."""
    if lazy:
        stream = FrameStream(n_steps, start)
        return LazyFrames(stream), LazyOrigins(stream)
    frames, origins = [], []
    for frame, origin in start():
        frames.append(frame)
        origins.append(origin)
    return frames, origins
