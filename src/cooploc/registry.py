"""The two registries (DESIGN §4–5): estimators by name, scenarios by preset name.

An estimator is a class with `name`, `summary`, `Params`, `needs_truth`,
`default_preset` (and optionally `required_sensors` and `usable_sensors`) and
`step(frame) -> Estimate`; it joins the registry through `register_estimator`, usable
as a class decorator:

    @register_estimator
    class MyKF:
        name = "my-kf"
        ...

A scenario family is a `generate(params, rng) -> Recording` with one or more named
`Preset`s of its `Params`; it joins through `register_scenario(family, generate,
presets)`. Registration also gives the Params class its owner for error messages
(`cooploc.params`): the estimator's name, or the scenario family's.

Where registrations come from, in order, the first time a registry is read:

1. cooploc's own modules (`BUILTIN_ESTIMATORS`, `BUILTIN_SCENARIOS`), imported here
   by name so that `import cooploc` stays light;
2. the entry points of installed packages in the groups ``cooploc.estimators`` and
   ``cooploc.scenarios``: each is loaded (its module imported, which may register
   what it holds), and an estimator class it names is registered;
3. anything registered at run time by calling `register_estimator` /
   `register_scenario` (a plug-in module imported by the user).

`unregister_estimator` / `unregister_scenario` take a registration back (for tests
and interactive sessions that register throw-away classes).

What an estimator can use. `usable_sensors` maps each measurement kind the method can
read to the sensor models (`SensorModel.name`, as `Setup.sensors` declares them) it can
read it from — the model says what the rows mean, e.g. ``"gnss-position"`` rows name
their vehicle, ``"anonymous-position"`` rows do not. `construct` refuses an estimator
that can use none of the kinds a scenario offers (it would return its prior and call
it an estimate), and `unused_kinds` names the kinds it accepts but leaves aside (the
run's summary and report say so). Where that depends on more than the sensor model (a
kind usable only together with another, or only in some parameter setting), the built
estimator says so itself: an attribute `left_aside` (a tuple of kinds) adds to what
`usable_sensors` rules out. A class without `usable_sensors` (a plug-in written
before it existed) is taken to use whatever it is given.

The bound of an estimator's own sensors. `bound` (optional) names the registered
known-association estimator that reads the same sensors — what the method could reach
if it knew the association (``"oracle-kf"`` for GNSS + V2F (+ odometry), ``"oracle-pose"`` for GNSS
+ radar, ``"kf-known-da"`` for GNSS alone), or None where cooploc has none. `cooploc
compare` gives each method's RMSE also as a ratio to it, beside the scenario's bound
(`Preset.bound`), which reads the scenario's main sensors: on a city with every
paper's sensors, a radar method is measured against what radar allows.

A plug-in that fails to load is reported with a `PluginWarning` and left out, so that
one broken package does not take `cooploc` down with it.
"""

from __future__ import annotations

import dataclasses
import importlib
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from cooploc.errors import ConfigError
from cooploc.params import Params, claim
from cooploc.types import AssociationTruth, Recording, Setup, Truth

__all__ = [
    "ESTIMATOR_GROUP",
    "SCENARIO_GROUP",
    "PluginWarning",
    "Preset",
    "estimators",
    "get_estimator",
    "get_preset",
    "make_estimator",
    "presets",
    "register_estimator",
    "register_scenario",
    "unregister_estimator",
    "unregister_scenario",
    "unused_kinds",
]

ESTIMATOR_GROUP = "cooploc.estimators"
SCENARIO_GROUP = "cooploc.scenarios"

BUILTIN_ESTIMATORS = (
    "cooploc.estimators.gnss_kf",
    "cooploc.estimators.oracle_kf",
    "cooploc.estimators.rsu_bp",
    "cooploc.estimators.icp",
    "cooploc.estimators.kf_known_da",
    "cooploc.estimators.oracle_pose",
    "cooploc.estimators.sme",
    "cooploc.estimators.gm_phd",
    "cooploc.estimators.factor_graph",
    "cooploc.estimators.plbp",
)
BUILTIN_SCENARIOS = (
    "cooploc.scenarios.froehle2018",
    "cooploc.scenarios.brambilla2020",
    "cooploc.scenarios.zhang2016",
    "cooploc.scenarios.gulati",
    "cooploc.scenarios.aoa_grid",
    "cooploc.scenarios.aoa_manhattan",
    "cooploc.scenarios.sumo",
)

#: what an estimator class must declare (DESIGN §4; `required_sensors`, `usable_sensors` are optional)
ESTIMATOR_ATTRIBUTES = ("name", "summary", "Params", "needs_truth", "default_preset", "step")

E = TypeVar("E", bound=type)


class PluginWarning(UserWarning):
    """An installed plug-in could not be loaded or registered; it is left out."""


@dataclass(frozen=True)
class Preset:
    """A named scenario: a family's parameters that reproduce a paper's setting.

    Attributes
    ----------
    name : what `cooploc run NAME` takes.
    params : the family's `Params` with this preset's values.
    summary : one line for `cooploc list`.
    doc : which figure or table it reproduces, and what the paper left unstated.
    bound : the registered estimator that bounds what the compared methods can reach on
        this scenario (a known-association reference using the same sensors, e.g.
        ``"oracle-kf"``), or None where no such reference exists; `cooploc compare`
        gives every method's RMSE as a ratio to it.
    family : the registered family (set by `register_scenario`).
    generator : the family's `generate(params, rng)` (set by `register_scenario`).
    """

    name: str
    params: Params
    summary: str
    doc: str = ""
    bound: str | None = None
    family: str = ""
    generator: Callable[[Any, np.random.Generator], Recording] | None = None

    def generate(self, rng: np.random.Generator, params: Params | None = None) -> Recording:
        """Simulate one run with `params` (default: the preset's own)."""
        if self.generator is None:
            raise ConfigError(f"preset {self.name!r} is not registered (see cooploc.register_scenario)")
        return self.generator(self.params if params is None else params, rng)


_estimators: dict[str, type] = {}
_presets: dict[str, Preset] = {}
_loaded = False


def _qualified(obj: Any) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', repr(obj))}"


def register_estimator(cls: E) -> E:
    """Add estimator class `cls` under `cls.name` (a class decorator; returns `cls`).

    Checks that it declares the interface of DESIGN §4 and that no other class holds
    the name; registering the same class again is a no-op. `cls.Params` takes the
    name for its error messages.
    """
    missing = [a for a in ESTIMATOR_ATTRIBUTES if not hasattr(cls, a)]
    if missing:
        raise ConfigError(f"{_qualified(cls)} is not an estimator: it lacks {', '.join(missing)}")
    name = cls.name
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{_qualified(cls)}.name must be a non-empty string, got {name!r}")
    if not (isinstance(cls.Params, type) and issubclass(cls.Params, Params)):
        raise ConfigError(f"{name}: Params must be a subclass of cooploc.params.Params, got {cls.Params!r}")
    if not isinstance(cls.needs_truth, bool):
        raise ConfigError(f"{name}: needs_truth must be True or False, got {cls.needs_truth!r}")
    own_bound = getattr(cls, "bound", None)
    if own_bound is not None and (not isinstance(own_bound, str) or not own_bound):
        raise ConfigError(f"{name}: bound must be an estimator name or None, got {own_bound!r}")
    if not callable(cls.step):
        raise ConfigError(f"{name}: step must be a method step(frame) -> Estimate")
    held = _estimators.get(name)
    if held is not None and held is not cls and _qualified(held) != _qualified(cls):
        raise ConfigError(f"estimator name {name!r} is registered already, by {_qualified(held)}")
    _estimators[name] = cls
    claim(cls.Params, name)
    return cls


def register_scenario(family: str, generate: Callable[[Any, np.random.Generator], Recording],
                      presets: Iterable[Preset]) -> tuple[Preset, ...]:
    """Add the presets of scenario family `family`, all generated by `generate`.

    Every preset's params must be of one `Params` class, which takes the family name
    for its error messages. Returns the registered presets (with `family` and
    `generator` set); a preset name held by another family is an error.
    """
    registered = tuple(dataclasses.replace(p, family=family, generator=generate) for p in presets)
    if not family or not registered:
        raise ConfigError(f"scenario family {family!r} needs a name and at least one preset")
    kinds = {type(p.params) for p in registered}
    if len(kinds) != 1 or not issubclass(next(iter(kinds)), Params):
        raise ConfigError(f"scenario family {family!r}: every preset's params must be of one Params "
                          f"class, got {sorted(k.__name__ for k in kinds)}")
    for preset in registered:
        held = _presets.get(preset.name)
        if held is not None and held.family != family:
            raise ConfigError(f"scenario {preset.name!r} is registered already, by family {held.family!r}")
    for preset in registered:
        _presets[preset.name] = preset
    claim(next(iter(kinds)), family)
    return registered


def _release(params_cls: type[Params], owner: str) -> None:
    """After `owner` was unregistered: if it named `params_cls`, the name passes to a
    registration that still uses the class, else the class takes its own name again."""
    if params_cls.__dict__.get("_owner") != owner:
        return
    params_cls._owner = None
    users = [name for name, cls in _estimators.items() if cls.Params is params_cls] + [
        p.family for p in _presets.values() if type(p.params) is params_cls]
    if users:
        claim(params_cls, users[0])


def unregister_estimator(name: str) -> type:
    """Remove the estimator registered as `name` and return its class.

    Its Params class no longer takes the name for its messages (`_release`). A built-in
    or plug-in estimator removed this way stays removed for the rest of the process
    (its module is imported only once).
    """
    cls = get_estimator(name)  # refuses an unknown name
    del _estimators[name]
    _release(cls.Params, name)
    return cls


def unregister_scenario(family: str) -> tuple[Preset, ...]:
    """Remove every preset of scenario family `family` and return them (see
    `unregister_estimator`)."""
    _load()
    removed = tuple(p for p in _presets.values() if p.family == family)
    if not removed:
        known = sorted({p.family for p in _presets.values()})
        raise ConfigError(f"unknown scenario family {family!r}; known: {', '.join(known)}")
    for preset in removed:
        del _presets[preset.name]
    _release(type(removed[0].params), family)
    return removed


def _load() -> None:
    """Import the built-in modules and the installed plug-ins, once."""
    global _loaded
    if _loaded:
        return
    _loaded = True  # first: the modules imported below call back into this registry
    try:
        for module in (*BUILTIN_ESTIMATORS, *BUILTIN_SCENARIOS):
            importlib.import_module(module)
    except BaseException:
        _loaded = False
        raise
    from importlib.metadata import entry_points

    for group in (ESTIMATOR_GROUP, SCENARIO_GROUP):
        for entry in entry_points(group=group):
            try:
                obj = entry.load()
                if group == ESTIMATOR_GROUP and isinstance(obj, type):
                    register_estimator(obj)
            except Exception as exc:  # a broken plug-in must not take cooploc down
                warnings.warn(f"cooploc: the plug-in {entry.name!r} ({entry.value}) of group {group} "
                              f"was left out: {type(exc).__name__}: {exc}", PluginWarning, stacklevel=2)


def estimators() -> dict[str, type]:
    """All registered estimator classes by name."""
    _load()
    return dict(_estimators)


def get_estimator(name: str) -> type:
    """The estimator class registered as `name`; `ConfigError` listing the known ones."""
    _load()
    if name not in _estimators:
        raise ConfigError(f"unknown estimator {name!r}; known: {', '.join(sorted(_estimators))}")
    return _estimators[name]


def presets() -> dict[str, Preset]:
    """All registered presets by name."""
    _load()
    return dict(_presets)


def get_preset(name: str) -> Preset:
    """The preset called `name`; `ConfigError` listing the known ones otherwise."""
    _load()
    if name not in _presets:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(sorted(_presets))}")
    return _presets[name]


def make_estimator(
    name: str,
    setup: Setup,
    params: Params | None,
    rng: np.random.Generator,
    truth: Truth | None = None,
) -> Any:
    """Construct estimator `name`; pass `truth` only to known-association references.

    A reference (`needs_truth`) receives only the association part of the truth
    (`AssociationTruth`); every other estimator receives none. A scenario without a
    measurement kind the estimator requires is refused with a `ConfigError`.
    """
    return construct(get_estimator(name), setup, params, rng, truth)


def _offered(setup: Setup) -> str:
    kinds = sorted(setup.sensors.items())
    return ", ".join(f"{kind} ({getattr(model, 'name', '?')})" for kind, model in kinds) or "none"


def unused_kinds(cls: type, setup: Setup, estimator: Any = None) -> tuple[str, ...] | None:
    """The measurement kinds of `setup` that estimator class `cls` leaves aside (sorted).

    A kind is used when `cls.usable_sensors` lists it with the setup's sensor model for
    it, and the built `estimator` (when given) does not name it in its `left_aside`.
    None when the class does not declare `usable_sensors`.
    """
    usable = getattr(cls, "usable_sensors", None)
    if usable is None:
        return None
    left_aside = set(getattr(estimator, "left_aside", ()))
    return tuple(kind for kind, model in sorted(setup.sensors.items())
                 if getattr(model, "name", None) not in usable.get(kind, ()) or kind in left_aside)


def construct(cls: type, setup: Setup, params: Params | None, rng: np.random.Generator,
              truth: Truth | None = None) -> Any:
    """`make_estimator` for a class (registered or not): the checks, then `cls(...)`.

    Refused with a `ConfigError`: a scenario without a kind in `cls.required_sensors`,
    or one of whose kinds `cls` can use none (`usable_sensors`, module docstring).
    """
    name = cls.name
    missing = [kind for kind in getattr(cls, "required_sensors", ()) if kind not in setup.sensors]
    if missing:
        raise ConfigError(f"{name} needs the measurement kinds {', '.join(missing)}, which this scenario "
                          f"does not have (it has: {', '.join(sorted(setup.sensors)) or 'none'})")
    unused = unused_kinds(cls, setup)
    if unused is not None and len(unused) == len(setup.sensors):
        usable = ", ".join(f"{kind} ({' or '.join(models)})" for kind, models in cls.usable_sensors.items())
        raise ConfigError(f"{name} can use nothing this scenario offers: it reads "
                          f"{usable or 'none'}; the scenario has {_offered(setup)}")
    params = cls.Params() if params is None else params
    if not isinstance(params, cls.Params):
        raise ConfigError(f"{name}: params must be {cls.Params.__name__}, got {type(params).__name__}")
    if cls.needs_truth:
        if truth is None:
            raise ConfigError(f"{name} is a known-association reference and needs the truth")
        return cls(setup, params, rng, truth=AssociationTruth.of(truth))
    return cls(setup, params, rng)
