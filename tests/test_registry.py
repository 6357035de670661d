"""The two registries (`cooploc.registry`): what they accept, what they refuse and why.

The registries are module state shared by the whole test session: every test here
registers under a throw-away name (`unique`) through the `registry` fixture, which
takes every registration back afterwards (`unregister_estimator` /
`unregister_scenario`). Discovery of installed plug-ins through entry points is
tested end to end in tests/integration/test_plugin.py; here the entry points are faked.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import uuid
from collections.abc import Callable, Iterator
from typing import Any, ClassVar

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.estimators.gnss_kf import GnssKF, GnssKFParams
from cooploc.params import Params, param
from cooploc.registry import (
    ESTIMATOR_ATTRIBUTES,
    ESTIMATOR_GROUP,
    SCENARIO_GROUP,
    PluginWarning,
    Preset,
    estimators,
    get_estimator,
    get_preset,
    make_estimator,
    presets,
    register_estimator,
    register_scenario,
    unregister_estimator,
    unregister_scenario,
)
from cooploc.scenarios.froehle2018 import FroehleParams
from cooploc.scenarios.froehle2018 import generate as froehle_generate
from cooploc.types import Recording
from helpers import froehle_recording


def unique(what: str) -> str:
    """A name no other test (or run) registers."""
    return f"test-{what}-{uuid.uuid4().hex[:8]}"


class Registrations:
    """Registers like the real functions, and remembers what to take back."""

    def __init__(self) -> None:
        self.names: list[str] = []
        self.families: list[str] = []

    def estimator(self, cls: type) -> type:
        self.names.append(cls.name)
        return register_estimator(cls)

    def scenario(self, family: str, generate: Callable[[Any, np.random.Generator], Recording],
                 presets: list[Preset]) -> tuple[Preset, ...]:
        self.families.append(family)
        return register_scenario(family, generate, presets)

    def take_back(self) -> None:
        for name in self.names:
            if name in estimators():
                unregister_estimator(name)
        for family in self.families:
            if family in {p.family for p in presets().values()}:
                unregister_scenario(family)


@pytest.fixture
def registry() -> Iterator[Registrations]:
    before = (set(estimators()), set(presets()))
    registrations = Registrations()
    yield registrations
    registrations.take_back()
    assert (set(estimators()), set(presets())) == before, "a test left a registration behind"


@dataclasses.dataclass(frozen=True)
class ToyParams(Params):
    """A Params class of the tests' own (claimed by whoever registers it first)."""

    n: int = param(3, ge=1)


def estimator_class(name: str, **attributes: Any) -> type:
    """A gnss-kf subclass registered as `name`, with attributes replaced."""
    return type("Toy", (GnssKF,), {"name": name, **attributes})


def toy_preset(name: str, params: Params | None = None) -> Preset:
    return Preset(name, FroehleParams(n_steps=3) if params is None else params, summary="a test preset")


# ----------------------------------------------------------------------------
# register_estimator
# ----------------------------------------------------------------------------


def test_a_registered_estimator_is_found_by_name(registry: Registrations) -> None:
    cls = registry.estimator(estimator_class(unique("found")))
    assert get_estimator(cls.name) is cls
    assert estimators()[cls.name] is cls


def _interface() -> dict[str, Any]:
    return {"name": unique("partial"), "summary": "s", "Params": GnssKFParams, "needs_truth": False,
            "default_preset": "froehle2018", "step": lambda self, frame: None}


@pytest.mark.parametrize("missing", ESTIMATOR_ATTRIBUTES)
def test_a_class_lacking_an_attribute_is_refused_naming_it(missing: str) -> None:
    attributes = _interface()
    del attributes[missing]
    cls = type("Partial", (), attributes)
    with pytest.raises(ConfigError, match=rf"Partial is not an estimator: it lacks {missing}$"):
        register_estimator(cls)
    assert attributes.get("name") not in estimators()


def test_every_missing_attribute_is_named_at_once() -> None:
    lacks = "it lacks name, summary, Params, needs_truth, default_preset, step"
    with pytest.raises(ConfigError, match=lacks):
        register_estimator(type("Empty", (), {}))


@pytest.mark.parametrize(("attribute", "value", "text"), [
    ("name", "", "name must be a non-empty string, got ''"),
    ("name", 3, "name must be a non-empty string, got 3"),
    ("Params", dict, "Params must be a subclass of cooploc.params.Params"),
    ("needs_truth", "no", "needs_truth must be True or False, got 'no'"),
    ("step", None, "step must be a method"),
])
def test_a_malformed_interface_is_refused(attribute: str, value: Any, text: str) -> None:
    attributes = {**_interface(), attribute: value}
    with pytest.raises(ConfigError, match=text):
        register_estimator(type("Malformed", (), attributes))


def test_a_second_class_under_a_taken_name_is_refused(registry: Registrations) -> None:
    name = unique("taken")

    class First(GnssKF):
        pass

    class Second(GnssKF):
        pass

    First.name = Second.name = name
    registry.estimator(First)
    with pytest.raises(ConfigError, match=rf"estimator name '{name}' is registered already, by .*First$"):
        register_estimator(Second)
    assert get_estimator(name) is First
    with pytest.raises(ConfigError, match=r"registered already, by cooploc\.estimators\.gnss_kf\.GnssKF$"):
        register_estimator(estimator_class("gnss-kf"))
    assert get_estimator("gnss-kf") is GnssKF


def test_registering_the_same_class_twice_is_a_no_op(registry: Registrations) -> None:
    cls = registry.estimator(estimator_class(unique("twice")))
    before = estimators()
    assert register_estimator(cls) is cls
    assert register_estimator(GnssKF) is GnssKF  # a built-in too
    assert estimators() == before


def test_registering_names_the_params_class_in_its_messages(registry: Registrations) -> None:
    @dataclasses.dataclass(frozen=True)
    class OwnParams(ToyParams):
        pass

    with pytest.raises(ConfigError, match=r"^test_registering_names_.*OwnParams: n must be >= 1, got 0$"):
        OwnParams(n=0)  # before registration: the class name
    name = unique("owner")
    registry.estimator(estimator_class(name, Params=OwnParams))
    with pytest.raises(ConfigError, match=rf"^{name}: n must be >= 1, got 0$"):
        OwnParams(n=0)
    with pytest.raises(ConfigError, match=rf"^{name}: unknown key 'm'; valid keys: n$"):
        OwnParams().with_overrides({"m": "1"})
    # a subclass registered under another name reuses the Params: the first name stays
    registry.estimator(estimator_class(unique("reuse"), Params=OwnParams))
    with pytest.raises(ConfigError, match=rf"^{name}: n must"):
        OwnParams(n=0)
    # taking the registrations back gives the class its own name again
    registry.take_back()
    with pytest.raises(ConfigError, match=r"^test_registering_names_.*OwnParams: n must"):
        OwnParams(n=0)


def test_the_built_in_params_are_named_by_their_registration() -> None:
    with pytest.raises(ConfigError, match=r"^froehle2018: n_vehicles must be >= 1, got 0$"):
        FroehleParams(n_vehicles=0)


# ----------------------------------------------------------------------------
# register_scenario and presets
# ----------------------------------------------------------------------------


def test_a_registered_scenario_generates_through_its_family(registry: Registrations) -> None:
    family = unique("family")
    seen: list[tuple[Params, np.random.Generator]] = []

    def generate(params: Params, rng: np.random.Generator) -> Recording:
        seen.append((params, rng))
        return froehle_generate(params, rng)  # type: ignore[arg-type]

    short, long = unique("short"), unique("long")
    registered = registry.scenario(family, generate, [
        toy_preset(short), toy_preset(long, FroehleParams(n_steps=5))])
    assert [p.name for p in registered] == [short, long]
    preset = get_preset(long)
    assert preset.family == family and preset.generator is generate
    rng = np.random.default_rng(0)
    recording = preset.generate(rng)
    assert seen == [(FroehleParams(n_steps=5), rng)] and len(recording.frames) == 5
    assert len(preset.generate(rng, FroehleParams(n_steps=2)).frames) == 2  # other params
    # registering the family's presets again (a reloaded module) is allowed
    registry.scenario(family, generate, [toy_preset(short)])


def test_a_preset_made_but_not_registered_cannot_generate() -> None:
    with pytest.raises(ConfigError, match=r"^preset 'loose' is not registered \(see cooploc\.register_"):
        toy_preset("loose").generate(np.random.default_rng(0))


def test_a_scenario_whose_presets_mix_params_classes_is_refused() -> None:
    family = unique("mixed")
    with pytest.raises(ConfigError, match=rf"scenario family '{family}': every preset's params must be of "
                                          r"one Params class, got \['FroehleParams', 'ToyParams'\]"):
        register_scenario(family, froehle_generate, [toy_preset(unique("a")), toy_preset(unique("b"),
                                                                                         ToyParams())])
    assert family not in {p.family for p in presets().values()}


def test_a_scenario_needs_a_name_and_presets() -> None:
    with pytest.raises(ConfigError, match="needs a name and at least one preset"):
        register_scenario("", froehle_generate, [toy_preset(unique("nameless"))])
    with pytest.raises(ConfigError, match="needs a name and at least one preset"):
        register_scenario(unique("empty"), froehle_generate, [])


def test_a_preset_name_of_another_family_is_refused(registry: Registrations) -> None:
    family = unique("thief")
    taken = "scenario 'froehle2018' is registered already, by family 'froehle2018'"
    with pytest.raises(ConfigError, match=taken):
        register_scenario(family, froehle_generate, [toy_preset(unique("fine")), toy_preset("froehle2018")])
    # nothing of the refused family was registered, not even its valid preset
    assert family not in {p.family for p in presets().values()}
    assert get_preset("froehle2018").family == "froehle2018"


def test_registering_names_the_scenario_params_class(registry: Registrations) -> None:
    @dataclasses.dataclass(frozen=True)
    class RoadParams(ToyParams):
        pass

    family = unique("road")
    registry.scenario(family, froehle_generate, [toy_preset(unique("road"), RoadParams())])
    with pytest.raises(ConfigError, match=rf"^{family}: n must be >= 1, got 0$"):
        RoadParams(n=0)


# ----------------------------------------------------------------------------
# look-ups and construction
# ----------------------------------------------------------------------------


def test_unknown_names_are_refused_listing_the_known_ones(registry: Registrations) -> None:
    name = registry.estimator(estimator_class(unique("listed"))).name
    with pytest.raises(ConfigError) as info:
        get_estimator("nope")
    text = str(info.value)
    assert text.startswith("unknown estimator 'nope'; known: ")
    assert {"gnss-kf", "oracle-kf", name} <= set(text.split("known: ")[1].split(", "))
    with pytest.raises(ConfigError) as info:
        get_preset("nowhere")
    text = str(info.value)
    assert text.startswith("unknown scenario 'nowhere'; known: ")
    assert {"froehle2018", "gulati-2v"} <= set(text.split("known: ")[1].split(", "))


def test_make_estimator_refuses_a_scenario_without_a_required_sensor(registry: Registrations) -> None:
    name = registry.estimator(estimator_class(unique("radar"), required_sensors=("radar", "gnss"))).name
    setup = froehle_recording(0).setup
    with pytest.raises(ConfigError, match=rf"^{name} needs the measurement kinds radar, which this scenario "
                                          r"does not have \(it has: gnss, v2f\)$"):
        make_estimator(name, setup, None, np.random.default_rng(0))


def test_make_estimator_checks_params_and_truth(registry: Registrations) -> None:
    recording = froehle_recording(0)
    est = make_estimator("gnss-kf", recording.setup, None, np.random.default_rng(0))
    assert isinstance(est, GnssKF) and est.params == GnssKFParams()
    with pytest.raises(ConfigError, match=r"^gnss-kf: params must be GnssKFParams, got ToyParams$"):
        make_estimator("gnss-kf", recording.setup, ToyParams(), np.random.default_rng(0))
    reference = "oracle-kf is a known-association reference and needs the truth"
    with pytest.raises(ConfigError, match=f"^{reference}$"):
        make_estimator("oracle-kf", recording.setup, None, np.random.default_rng(0))


# ----------------------------------------------------------------------------
# unregistering
# ----------------------------------------------------------------------------


def test_unregister_takes_a_registration_back(registry: Registrations) -> None:
    cls = registry.estimator(estimator_class(unique("gone")))
    assert unregister_estimator(cls.name) is cls
    assert cls.name not in estimators()
    with pytest.raises(ConfigError, match=rf"unknown estimator '{cls.name}'"):
        unregister_estimator(cls.name)
    family, a, b = unique("gone"), unique("a"), unique("b")
    registered = registry.scenario(family, froehle_generate, [toy_preset(a), toy_preset(b)])
    assert unregister_scenario(family) == registered
    assert not {a, b} & set(presets())
    with pytest.raises(ConfigError, match=rf"unknown scenario family '{family}'; known: .*froehle2018"):
        unregister_scenario(family)


# ----------------------------------------------------------------------------
# discovery through entry points (faked; the real thing: tests/integration/test_plugin.py)
# ----------------------------------------------------------------------------


class Discovered(GnssKF):
    """An estimator that only an entry point names (no decorator)."""

    name: ClassVar[str] = "test-discovered-kf"


def test_entry_points_register_estimators_and_leave_broken_ones_out(
        monkeypatch: pytest.MonkeyPatch, registry: Registrations) -> None:
    fakes = {
        ESTIMATOR_GROUP: [
            importlib.metadata.EntryPoint("good", f"{__name__}:Discovered", ESTIMATOR_GROUP),
            importlib.metadata.EntryPoint("broken", "cooploc_no_such_module:Estimator", ESTIMATOR_GROUP),
        ],
        SCENARIO_GROUP: [
            importlib.metadata.EntryPoint("also-broken", "cooploc_no_such_module", SCENARIO_GROUP),
        ],
    }
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: fakes.get(group, []))
    monkeypatch.setattr("cooploc.registry._loaded", False)  # read the (fake) entry points again
    registry.names.append(Discovered.name)
    with pytest.warns(PluginWarning) as warned:
        found = estimators()
    assert found["test-discovered-kf"] is Discovered
    assert "gnss-kf" in found  # one broken plug-in takes nothing else down
    messages = [str(w.message) for w in warned]
    assert len(messages) == 2
    assert "the plug-in 'broken' (cooploc_no_such_module:Estimator) of group cooploc.estimators was left " \
           "out: ModuleNotFoundError" in messages[0]
    assert "'also-broken'" in messages[1] and "group cooploc.scenarios" in messages[1]
