"""Declarative parameter constraints (`cooploc.params.param`) and their messages.

Every failure is one line, ``"{owner}: {key} must {what}, got {value!r}"``; the owner is
the name the class is registered under (tests/test_registry.py), else the class name.
Overrides from strings and TOML are tested in tests/test_types.py.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cooploc.errors import ConfigError
from cooploc.params import Constraint, Params, param


@dataclasses.dataclass(frozen=True)
class Knobs(Params):
    """One field for each kind of constraint (the class is never registered)."""

    rate: float = param(1.0, gt=0)
    count: int = param(2, ge=1)
    share: float = param(0.5, gt=0, le=1)
    below_one: float = param(0.5, ge=0, lt=1)
    at_most_five: float = param(1.0, le=5)
    negative: float = param(-1.0, lt=0)
    lanes: int = param(3, ge=1, le=5)
    width: float = param(3.0, ge=1, le=5)
    offset: float = param(0.0, finite=True)
    variances: tuple[float, ...] = param((1.0, 2.0), gt=0, min_length=1)
    pair: tuple[float, ...] = param((0.0, 1.0), length=2)
    sizes: tuple[int, ...] = param((1, 2), min_length=2)
    mode: str = param("road", choices=("road", "crossroad"))
    method: str = param("a", choices=("a", "b", "c"))
    gain: float = param(1.0, gt=0, must="be a positive gain")
    limit: float | None = param(None, gt=0)


def message(key: str, value: Any) -> str:
    with pytest.raises(ConfigError) as info:
        Knobs(**{key: value})
    return str(info.value)


def test_defaults_are_valid_and_constraints_are_listed() -> None:
    Knobs()
    constraints = Knobs.constraints()
    assert set(constraints) == {f.name for f in dataclasses.fields(Knobs)}
    assert constraints["share"] == Constraint(gt=0, le=1)


@pytest.mark.parametrize(("key", "value", "what"), [
    ("rate", 0.0, "be > 0"),
    ("rate", -2.5, "be > 0"),
    ("count", 0, "be >= 1"),
    ("share", 0.0, "lie in (0, 1]"),
    ("share", 1.5, "lie in (0, 1]"),
    ("below_one", 1.0, "lie in [0, 1)"),
    ("at_most_five", 5.5, "be <= 5"),
    ("negative", 0.0, "be < 0"),
    ("lanes", 0, "lie in 1..5"),      # an integer range reads as the integers it admits
    ("lanes", 6, "lie in 1..5"),
    ("width", 0.5, "lie in [1, 5]"),  # the same bounds on a float: an interval
    ("offset", math.inf, "be finite"),
    ("rate", math.inf, "be > 0"),     # a bound implies finiteness
    ("rate", math.nan, "be > 0"),
    ("variances", (1.0, 0.0), "have every entry > 0"),
    ("variances", (), "have at least one entry"),
    ("pair", (1.0, 2.0, 3.0), "have 2 entries"),
    ("sizes", (1,), "have at least 2 entries"),
    ("mode", "street", "be 'road' or 'crossroad'"),
    ("method", "d", "be one of 'a', 'b', 'c'"),
    ("gain", 0.0, "be a positive gain"),  # `must` replaces the generated text
    ("limit", -1.0, "be > 0"),
])
def test_each_constraint_has_its_message(key: str, value: Any, what: str) -> None:
    assert message(key, value) == f"Knobs: {key} must {what}, got {value!r}"


@pytest.mark.parametrize(("key", "value"), [
    ("rate", 1e-300), ("count", 1), ("share", 1.0), ("below_one", 0.0), ("at_most_five", 5.0),
    ("lanes", 1), ("lanes", 5), ("width", 5.0), ("offset", -1e300), ("variances", (3.0,)),
    ("pair", (-1.0, 1.0)), ("sizes", (0, 0, 0)), ("mode", "crossroad"), ("method", "c"),
    ("limit", None), ("limit", 2.0),
])
def test_values_on_the_right_side_of_a_bound_pass(key: str, value: Any) -> None:
    assert getattr(Knobs(**{key: value}), key) == value


def test_bounds_apply_to_every_tuple_entry_and_to_no_bound_less_field() -> None:
    assert message("variances", (1.0, math.inf)) == (
        "Knobs: variances must have every entry > 0, got (1.0, inf)")
    # `sizes` declares only a length: its entries may be anything
    assert Knobs(sizes=(-5, 7)).sizes == (-5, 7)


def test_types_are_checked_before_constraints() -> None:
    assert message("count", "two") == "Knobs: count must be an integer, got 'two'"
    assert Knobs(count=3.0).count == 3       # an integral float is an integer
    assert message("count", True) == "Knobs: count must be an integer, got True"
    assert Knobs(variances=[4, 5]).variances == (4.0, 5.0)  # lists from TOML become tuples


def test_fields_are_checked_in_order() -> None:
    # two failing fields: the message names the first declared
    with pytest.raises(ConfigError, match=r"^Knobs: rate must"):
        Knobs(rate=0.0, count=0)


@dataclasses.dataclass(frozen=True)
class Window(Params):
    """A cross-field rule in `validate()` on top of the declared bounds."""

    low: float = param(0.0, ge=0)
    high: float = param(1.0, gt=0)

    def validate(self) -> None:
        self.require(self.high > self.low, "high", f"be greater than low = {self.low:g}")


@dataclasses.dataclass(frozen=True)
class NarrowWindow(Window):
    """A subclass: inherits both the declared constraints and `validate()`."""

    width: float = param(0.5, gt=0, le=1)


def test_validate_checks_what_involves_several_fields() -> None:
    with pytest.raises(ConfigError) as info:
        Window(low=2.0, high=1.5)
    assert str(info.value) == "Window: high must be greater than low = 2, got 1.5"


def test_declared_constraints_run_before_validate() -> None:
    with pytest.raises(ConfigError, match=r"^Window: low must be >= 0, got -1\.0$"):
        Window(low=-1.0, high=-2.0)


def test_subclasses_inherit_constraints_and_validate() -> None:
    with pytest.raises(ConfigError, match=r"^NarrowWindow: low must be >= 0, got -1\.0$"):
        NarrowWindow(low=-1.0)
    with pytest.raises(ConfigError, match=r"^NarrowWindow: high must be greater than low"):
        NarrowWindow(low=3.0, high=2.0)
    with pytest.raises(ConfigError, match=r"^NarrowWindow: width must lie in \(0, 1\], got 2\.0$"):
        NarrowWindow(width=2.0)
    assert set(NarrowWindow.constraints()) == {"low", "high", "width"}


def test_replace_and_overrides_are_checked_too() -> None:
    with pytest.raises(ConfigError, match=r"^Knobs: share must lie in \(0, 1\], got 2\.0$"):
        dataclasses.replace(Knobs(), share=2.0)
    with pytest.raises(ConfigError, match=r"^Knobs: lanes must lie in 1\.\.5, got 9$"):
        Knobs().with_overrides({"lanes": "9"})


# ----------------------------------------------------------------------------
# properties: a value is accepted exactly when it satisfies every bound
# ----------------------------------------------------------------------------

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


def bounded(low: float | None, high: float | None, strict_low: bool, strict_high: bool) -> type[Params]:
    """A Params class with one float field `x` under the given bounds."""
    bounds = {("gt" if strict_low else "ge"): low, ("lt" if strict_high else "le"): high}
    field = param(None, **{k: v for k, v in bounds.items() if v is not None})
    return dataclasses.make_dataclass("Bounded", [("x", float | None, field)], bases=(Params,), frozen=True)


def holds(x: float, low: float | None, high: float | None, strict_low: bool, strict_high: bool) -> bool:
    if not math.isfinite(x):
        return False
    above = low is None or (x > low if strict_low else x >= low)
    below = high is None or (x < high if strict_high else x <= high)
    return above and below


@settings(max_examples=300, deadline=None)
@given(x=st.one_of(finite, st.sampled_from([math.inf, -math.inf, math.nan])),
       low=st.none() | finite, high=st.none() | finite, strict_low=st.booleans(),
       strict_high=st.booleans())
def test_a_number_is_accepted_exactly_when_it_satisfies_its_bounds(
        x: float, low: float | None, high: float | None, strict_low: bool, strict_high: bool) -> None:
    cls = bounded(low, high, strict_low, strict_high)
    if low is None and high is None:
        kept = cls(x=x).x  # nothing declared, nothing checked
        assert kept == x or (math.isnan(x) and math.isnan(kept))
        return
    if holds(x, low, high, strict_low, strict_high):
        assert cls(x=x).x == x
    else:
        with pytest.raises(ConfigError) as info:
            cls(x=x)
        text = str(info.value)
        assert text.startswith("Bounded: x must ") and text.endswith(f", got {x!r}")
        assert re.fullmatch(r"Bounded: x must (be [<>]=? \S+|lie in [\[(]\S+, \S+[\])]), got .+", text)


@settings(max_examples=200, deadline=None)
@given(entries=st.lists(finite, max_size=6))
def test_a_tuple_is_accepted_exactly_when_every_entry_is_positive(entries: list[float]) -> None:
    if entries and all(v > 0 for v in entries):
        assert Knobs(variances=tuple(entries)).variances == tuple(entries)
    else:
        text = message("variances", tuple(entries))
        assert text.startswith("Knobs: variances must have ")
        assert text.endswith(f", got {tuple(entries)!r}")
