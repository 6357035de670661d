"""The configuration of a Monte Carlo experiment (DESIGN §6): what `config.toml` holds.

`ExperimentConfig` is the fully resolved configuration — scenario preset and its
parameters, estimators with theirs, runs, seed, backend, workers, the Dask scheduler
address — built from names and
overrides (`build`, the command line's `--set`/`--est-set` strings parsed by the
parameters' types), read back from `config.toml` (`from_dict`, every key and type
checked: a mistake is one `ConfigError` naming the key and value), and changed by the
command line's overrides of a `--config` rerun (`with_overrides`). `same_experiment`
tells whether two configurations give the same numbers (backend, workers and scheduler
aside), which decides whether a results folder may be written over or resumed.

Running it is `cooploc.experiment`; writing its results, `cooploc.results`.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cooploc._version import __version__
from cooploc.backends import BACKENDS
from cooploc.errors import ConfigError
from cooploc.params import Params
from cooploc.registry import get_estimator, get_preset

__all__ = ["EstimatorSpec", "ExperimentConfig"]

@dataclass(frozen=True)
class EstimatorSpec:
    """An estimator by registered name with its resolved parameters."""

    name: str
    params: Params

    @classmethod
    def of(cls, name: str, overrides: Mapping[str, Any] | None = None) -> EstimatorSpec:
        est = get_estimator(name)
        return cls(name, est.Params().with_overrides(overrides or {}))


@dataclass(frozen=True)
class ExperimentConfig:
    """The fully resolved configuration of a Monte Carlo experiment."""

    scenario: str
    scenario_params: Params
    estimators: tuple[EstimatorSpec, ...]
    runs: int = 10
    seed: int = 0
    backend: str = "processes"
    workers: int | None = None
    scheduler: str | None = None  # address of a running Dask scheduler (backend "dask")

    def __post_init__(self) -> None:
        for key, value, low in (("runs", self.runs, 1), ("seed", self.seed, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                what = "a positive" if low == 1 else "a non-negative"
                raise ConfigError(f"{key} must be {what} integer, got {value!r}")
        self.check_backend(self.backend, self.workers, self.scheduler)
        if not self.estimators:
            raise ConfigError("at least one estimator is needed (-e NAME)")
        names = [e.name for e in self.estimators]
        if len(set(names)) != len(names):
            raise ConfigError(f"estimators are listed twice: {names}")

    @staticmethod
    def check_backend(backend: Any, workers: Any, scheduler: Any = None) -> None:
        """Refuse an unknown backend, a bad worker count, workers with the serial backend, or a
        scheduler address with another backend than dask, or with workers (a running
        cluster has the workers it has)."""
        if not isinstance(backend, str) or backend not in BACKENDS:
            raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ConfigError(f"workers must be a positive integer, got {workers!r}")
        if workers is not None and backend == "serial":
            # a worker count that nothing uses would be silently ignored
            raise ConfigError(f"workers apply to the processes and dask backends, not serial; "
                              f"got workers = {workers}")
        if scheduler is None:
            return
        if not isinstance(scheduler, str) or not scheduler.strip() or any(c.isspace() for c in scheduler):
            raise ConfigError(f"scheduler must be the address of a Dask scheduler (tcp://HOST:PORT), "
                              f"got {scheduler!r}")
        if backend != "dask":
            raise ConfigError(f"a scheduler address applies to the dask backend, not {backend}; "
                              f"got scheduler = {scheduler!r} (add --backend dask)")
        if workers is not None:
            raise ConfigError(f"workers size a local cluster; the cluster at {scheduler} has its own "
                              f"workers; got workers = {workers}")

    @classmethod
    def build(
        cls,
        scenario: str,
        estimators: Sequence[str],
        *,
        scenario_overrides: Mapping[str, Any] | None = None,
        estimator_overrides: Mapping[str, Mapping[str, Any]] | None = None,
        runs: int = 10,
        seed: int = 0,
        backend: str = "processes",
        workers: int | None = None,
        scheduler: str | None = None,
    ) -> ExperimentConfig:
        """Resolve names and overrides (strings are parsed by the params' field types)."""
        preset = get_preset(scenario)
        specs = _specs(estimators, {}, estimator_overrides or {})
        return cls(scenario, preset.params.with_overrides(scenario_overrides or {}), specs,
                   runs, seed, backend, workers, scheduler)

    def with_overrides(
        self,
        estimators: Sequence[str] | None = None,
        *,
        scenario_overrides: Mapping[str, Any] | None = None,
        estimator_overrides: Mapping[str, Mapping[str, Any]] | None = None,
        runs: int | None = None,
        seed: int | None = None,
        backend: str | None = None,
        workers: int | None = None,
        scheduler: str | None = None,
    ) -> ExperimentConfig:
        """A copy with what is given replaced (`cooploc run --config FILE` plus options).

        `estimators` replaces the list: an estimator already in the config keeps its
        parameters, a new one starts from its defaults; then `estimator_overrides` and
        `scenario_overrides` are applied on top (strings parsed as in `build`). A backend
        given without workers drops the config's workers where the backend takes none, and
        the config's scheduler unless it is dask; a scheduler given drops the workers.
        """
        names = [e.name for e in self.estimators] if estimators is None else list(estimators)
        backend = self.backend if backend is None else backend
        if scheduler is None and backend == "dask" and workers is None:
            scheduler = self.scheduler
        if workers is None and backend != "serial" and scheduler is None:
            workers = self.workers
        return type(self)(
            self.scenario, self.scenario_params.with_overrides(scenario_overrides or {}),
            _specs(names, {e.name: e.params for e in self.estimators}, estimator_overrides or {}),
            self.runs if runs is None else runs, self.seed if seed is None else seed, backend, workers,
            scheduler)

    def to_dict(self) -> dict[str, Any]:
        """Everything needed to rerun, as plain data (written to config.toml)."""
        return {
            "cooploc_version": __version__,
            "scenario": self.scenario,
            "runs": self.runs,
            "seed": self.seed,
            "backend": self.backend,
            "workers": self.workers,
            "scheduler": self.scheduler,
            "scenario_params": self.scenario_params.to_dict(),
            "estimators": {e.name: e.params.to_dict() for e in self.estimators},
        }

    @classmethod
    def read(cls, path: str | os.PathLike[str]) -> ExperimentConfig:
        """The configuration in a `config.toml` file (`from_dict` of its table).

        A missing file or one that is not TOML is a `ConfigError` naming the path.
        """
        if sys.version_info >= (3, 11):
            import tomllib
        else:  # pragma: no cover - Python 3.10
            import tomli as tomllib
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"no such file {str(path)!r}")
        try:
            data = tomllib.loads(path.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path} is not valid TOML: {exc}") from None
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ExperimentConfig:
        """Inverse of `to_dict` (e.g. a config.toml written by `cooploc run`).

        `scenario_params` may name only some keys: the others are the preset's.
        Every key is checked: an unknown key, or a value of the wrong kind (e.g.
        `estimators` not a table of tables), is a `ConfigError` naming key and value.
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"configuration must be a table of keys, got {data!r}")
        unknown = sorted(set(data) - set(_CONFIG_KEYS))
        if unknown:
            raise ConfigError(f"configuration: unknown key {unknown[0]!r}; "
                              f"valid keys: {', '.join(_CONFIG_KEYS)}")
        if "scenario" not in data:
            raise ConfigError("configuration is missing the key 'scenario'")
        scenario = data["scenario"]
        if not isinstance(scenario, str):
            raise ConfigError(f"configuration: scenario must be a preset name, got {scenario!r}")
        preset = get_preset(scenario)
        scenario_params = data.get("scenario_params", {})
        if not isinstance(scenario_params, Mapping):
            raise ConfigError(f"configuration: scenario_params must be a table of parameters, "
                              f"got {scenario_params!r}")
        estimators = data.get("estimators", {})
        if not isinstance(estimators, Mapping):
            raise ConfigError("configuration: estimators must be a table of estimator tables "
                              f"([estimators.NAME]), got {estimators!r}")
        specs = []
        for name, params in estimators.items():
            if not isinstance(params, Mapping):
                raise ConfigError(f"configuration: estimators.{name} must be a table of parameters, "
                                  f"got {params!r}")
            specs.append(EstimatorSpec(name, get_estimator(name).Params.from_dict(params)))
        # keys left out keep the preset's values (not the parameter class's defaults, which
        # for the SUMO presets would be the grid's network)
        return cls(scenario, preset.params.with_overrides(scenario_params), tuple(specs),
                   runs=data.get("runs", 10), seed=data.get("seed", 0),
                   backend=data.get("backend", "processes"), workers=data.get("workers"),
                   scheduler=data.get("scheduler"))

    def same_experiment(self, other: ExperimentConfig) -> bool:
        """Whether `other` gives the same numbers: all but the backend, the workers and the
        scheduler agree."""
        def numbers(config: ExperimentConfig) -> ExperimentConfig:
            return dataclasses.replace(config, backend="serial", workers=None, scheduler=None)

        return numbers(self) == numbers(other)

    def differences(self, other: ExperimentConfig) -> list[tuple[str, Any, Any]]:
        """(key, value here, value in `other`) of every setting that changes the numbers and
        differs (backend, workers and scheduler do not count); dotted keys inside
        scenario_params and estimators, e.g. ``scenario_params.n_steps``. Empty where only
        the order of the estimators differs."""
        ignored = ("cooploc_version", "backend", "workers", "scheduler")
        mine, theirs = self.to_dict(), other.to_dict()
        out = []
        for key in mine:
            if key in ignored or mine[key] == theirs[key]:
                continue
            if isinstance(mine[key], Mapping) and isinstance(theirs[key], Mapping):
                for sub in sorted(set(mine[key]) | set(theirs[key])):
                    if mine[key].get(sub) != theirs[key].get(sub):
                        out.append((f"{key}.{sub}", mine[key].get(sub), theirs[key].get(sub)))
            else:
                out.append((key, mine[key], theirs[key]))
        return out


def _specs(names: Sequence[str], params: Mapping[str, Params],
           overrides: Mapping[str, Mapping[str, Any]]) -> tuple[EstimatorSpec, ...]:
    """Specs of `names`: their `params` where given, else defaults, with `overrides` applied."""
    stray = sorted(set(overrides) - set(names))
    if stray:
        raise ConfigError(f"--est-set names estimator {stray[0]!r}, which is not in -e: {list(names)}")
    return tuple(EstimatorSpec(n, params[n].with_overrides(overrides.get(n, {}))) if n in params
                 else EstimatorSpec.of(n, overrides.get(n)) for n in names)


#: the keys of `ExperimentConfig.to_dict` (config.toml)
_CONFIG_KEYS = ("cooploc_version", "scenario", "runs", "seed", "backend", "workers", "scheduler",
                "scenario_params", "estimators")
