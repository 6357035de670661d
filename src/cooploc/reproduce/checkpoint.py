"""What a paper experiment has finished, kept on disk so `reproduce --resume` goes on.

A paper experiment is many experiments (figures, sweep points) and other tasks
(`ReproduceContext.map`). Each finished unit is written to ``OUT/runs/`` as it
finishes, under a key that depends only on what determines its numbers:

- a run: the experiment's settings except backend, workers and scheduler (as
  `ExperimentConfig.same_experiment`), and the run number — so a study interrupted
  under one backend resumes under another with the same numbers;
- a task of `map`: the pickled function (its name, and a partial's bound arguments)
  and the pickled task.

Units are pickled whole (a `RunResult` or a task's return value; floats keep their
bits) and written atomically, so a killed process leaves only complete units. Without
``--resume`` an experiment clears the folder first; a finished experiment removes it.
The folder is a cache of this machine's own results: load it only from folders you
wrote (pickle runs code when it loads).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import pickle
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from cooploc.config import ExperimentConfig

__all__ = ["FOLDER", "Checkpoint"]

FOLDER = "runs"
SUFFIX = ".pkl"


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:20]


def config_key(config: ExperimentConfig) -> str:
    """A key of the numbers of `config` (backend, workers, scheduler and version left out)."""
    numbers = dataclasses.replace(config, backend="serial", workers=None, scheduler=None).to_dict()
    numbers.pop("cooploc_version", None)
    return _digest(json.dumps(numbers, sort_keys=True, default=str).encode())


def task_key(fn: Callable[[Any], Any], task: Any) -> str:
    """A key of one `map` task: the pickled function (a module-level one by its name, a
    `functools.partial` with its bound arguments) and the pickled task."""
    return _digest(pickle.dumps((fn, task), protocol=5))


class Checkpoint:
    """The finished units of one paper experiment in ``out/runs/``.

    Parameters
    ----------
    out : the experiment's results folder.
    resume : keep what an earlier, interrupted experiment left (else clear it).
    """

    def __init__(self, out: Path, resume: bool) -> None:
        self.folder = Path(out) / FOLDER
        self.folder.mkdir(parents=True, exist_ok=True)
        if not resume:
            self.clear()

    def _path(self, key: str) -> Path:
        return self.folder / f"{key}{SUFFIX}"

    def run_key(self, config: ExperimentConfig, run: int) -> str:
        return f"{config_key(config)}-run-{run:06d}"

    def load(self, key: str) -> tuple[bool, Any]:
        """(True, the unit) if `key` finished earlier, else (False, None); a unit that cannot
        be read (e.g. written by another cooploc version) counts as not finished."""
        path = self._path(key)
        if not path.is_file():
            return False, None
        try:
            with path.open("rb") as f:
                return True, pickle.load(f)
        except Exception:  # an unreadable unit is computed again, whatever the reason
            return False, None

    def held(self, keys: Sequence[str]) -> dict[int, Any]:
        """{i: unit} of the `keys[i]` that finished earlier (`load`)."""
        out = {}
        for i, key in enumerate(keys):
            found, value = self.load(key)
            if found:
                out[i] = value
        return out

    def save(self, key: str, value: Any) -> None:
        path = self._path(key)
        part = path.with_name(f".{path.name}.{os.getpid()}.part")
        with part.open("wb") as f:
            pickle.dump(value, f, protocol=5)
        os.replace(part, path)

    def clear(self) -> None:
        """Remove every unit and stray partial file."""
        for path in [*self.folder.glob(f"*{SUFFIX}"), *self.folder.glob(f".*{SUFFIX}.*.part")]:
            path.unlink(missing_ok=True)

    def remove(self) -> None:
        """Clear, and remove the folder unless it holds files that are not ours."""
        self.clear()
        try:
            self.folder.rmdir()
        except OSError:
            pass
