"""Declarative parameters: frozen dataclasses with defaults, declared constraints and overrides.

Scenario and estimator parameters subclass `Params`. A subclass lists its fields with
type hints and paper defaults; a field's constraints stand beside it:

    @dataclass(frozen=True)
    class RsuBPParams(Params):
        n_particles: int = param(600, ge=2)
        resample_threshold: float = param(0.5, ge=0.0, le=1.0)
        feature_init: str = param("measurements", choices=("measurements", "prior"))

One mechanism checks them all when an instance is made: first the type of every field
(strings parsed, int → float, list → tuple), then each field's constraints in field
order, then `validate()`, where a subclass checks what involves several fields with
`self.require(condition, key, must)`. A failure raises `ConfigError` with one line,
``"{owner}: {key} must {what}, got {value!r}"``, where the owner is the name the class
is registered under (the estimator's name or the scenario family, set by
`cooploc.registry`), or the class name before it is registered.

Users override fields from Python (`dataclasses.replace`), from TOML, or from the
command line (`with_overrides({"n_features": "5"})`), where strings are parsed by the
field's type; an unknown key raises `ConfigError` listing the valid ones.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, TypeVar

from cooploc.errors import ConfigError

__all__ = ["Constraint", "Params", "param"]

P = TypeVar("P", bound="Params")

_METADATA_KEY = "cooploc.constraint"


@dataclasses.dataclass(frozen=True)
class Constraint:
    """What a field's value must satisfy (every given bound; numbers and tuple entries).

    Bounds (`gt`, `ge`, `lt`, `le`) and `finite` apply to a number, or to every entry of
    a tuple; `length` and `min_length` to the tuple itself; `choices` to the value.
    A bound implies finiteness (inf is not "> 0"). `must` replaces the generated text
    of the message ("be > 0", "lie in (0, 1]", "be 'road' or 'crossroad'").
    """

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    finite: bool = False
    choices: tuple[Any, ...] | None = None
    length: int | None = None
    min_length: int | None = None
    must: str | None = None

    def failure(self, value: Any, integer: bool = False) -> str | None:
        """What `value` (already of the field's type) must do but does not, or None if it
        satisfies every part: "be >= 1", "lie in (0, 1]", "have at least one entry"."""
        if value is None:
            return None
        if self.choices is not None:
            if value in self.choices:
                return None
            shown = [repr(c) for c in self.choices]
            return self.must or (f"be {shown[0]} or {shown[1]}" if len(shown) == 2
                                 else f"be one of {', '.join(shown)}")
        if isinstance(value, tuple):
            if self.length is not None and len(value) != self.length:
                return self.must or f"have {self.length} entries"
            if self.min_length is not None and len(value) < self.min_length:
                return self.must or ("have at least one entry" if self.min_length == 1
                                     else f"have at least {self.min_length} entries")
            if all(self._number_holds(v) for v in value):
                return None
            bounds = self._bounds(integer)            # "be > 0" → "have every entry > 0"
            return self.must or "have every entry " + bounds.split(" ", 1)[1].removeprefix("in ")
        return None if self._number_holds(value) else self.must or self._bounds(integer)

    def _number_holds(self, value: Any) -> bool:
        if not (self.finite or self._bounded) or isinstance(value, str):
            return True
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return False
        return ((self.gt is None or value > self.gt) and (self.ge is None or value >= self.ge)
                and (self.lt is None or value < self.lt) and (self.le is None or value <= self.le))

    @property
    def _bounded(self) -> bool:
        return any(b is not None for b in (self.gt, self.ge, self.lt, self.le))

    def _bounds(self, integer: bool) -> str:
        """The bounds as the message says them: "be > 0", "lie in (0, 1]", "lie in 1..5"."""
        low = ((self.gt, "(", ">") if self.gt is not None
               else (self.ge, "[", ">=") if self.ge is not None else None)
        high = ((self.lt, ")", "<") if self.lt is not None
                else (self.le, "]", "<=") if self.le is not None else None)
        if low is not None and high is not None:
            if integer and self.ge is not None and self.le is not None:
                return f"lie in {_number(self.ge)}..{_number(self.le)}"
            return f"lie in {low[1]}{_number(low[0])}, {_number(high[0])}{high[1]}"
        if low is not None or high is not None:
            bound, _, op = low if low is not None else high
            return f"be {op} {_number(bound)}"
        return "be finite"


def _number(x: float) -> str:
    return f"{x:g}"


def param(default: Any, *, gt: float | None = None, ge: float | None = None, lt: float | None = None,
          le: float | None = None, finite: bool = False, choices: Sequence[Any] | None = None,
          length: int | None = None, min_length: int | None = None, must: str | None = None) -> Any:
    """A `Params` field with its default and its constraints (see `Constraint`).

    >>> @dataclass(frozen=True)
    ... class MyParams(Params):
    ...     n_particles: int = param(600, ge=2)
    ...     threshold: float = param(0.5, gt=0.0, le=1.0)      # "lie in (0, 1]"
    """
    constraint = Constraint(gt, ge, lt, le, finite, None if choices is None else tuple(choices),
                            length, min_length, must)
    return dataclasses.field(default=default, metadata={_METADATA_KEY: constraint})


@dataclasses.dataclass(frozen=True)
class Params:
    """Base of every scenario and estimator parameter set (see the module docstring)."""

    #: the registered name used in error messages; set by `cooploc.registry` on the class itself
    _owner: ClassVar[str | None] = None

    def __post_init__(self) -> None:
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, list):  # TOML and JSON give lists where we keep tuples
                object.__setattr__(self, f.name, tuple(value))
            try:
                coerced = _coerce(getattr(self, f.name), hints[f.name])
            except (TypeError, ValueError) as exc:
                raise ConfigError(
                    f"{self.owner()}: {f.name} must be {_type_name(hints[f.name])}, "
                    f"got {value!r}"
                ) from exc
            object.__setattr__(self, f.name, coerced)
        for f in dataclasses.fields(self):
            constraint = f.metadata.get(_METADATA_KEY)
            failure = None if constraint is None else constraint.failure(
                getattr(self, f.name), integer=hints[f.name] is int)
            if failure is not None:
                self.require(False, f.name, failure)
        self.validate()

    @classmethod
    def owner(cls) -> str:
        """Name used in error messages: the registered name, else the class name."""
        return cls.__dict__.get("_owner") or cls.__qualname__

    def validate(self) -> None:
        """Check what involves several fields; subclasses override and call `require`."""

    def require(self, condition: bool, key: str, must: str) -> None:
        """Raise `ConfigError("{owner}: {key} must {must}, got {value!r}")` unless `condition`."""
        if not condition:
            raise ConfigError(f"{self.owner()}: {key} must {must}, got {getattr(self, key)!r}")

    @classmethod
    def constraints(cls) -> dict[str, Constraint]:
        """The declared constraint of every field that has one."""
        return {f.name: f.metadata[_METADATA_KEY] for f in dataclasses.fields(cls)
                if _METADATA_KEY in f.metadata}

    @classmethod
    def keys(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (tuples as lists) for JSON and TOML."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls: type[P], data: Mapping[str, Any]) -> P:
        unknown = sorted(set(data) - set(cls.keys()))
        if unknown:
            raise cls._unknown_key(unknown[0])
        return cls(**dict(data))

    @classmethod
    def _unknown_key(cls, key: str) -> ConfigError:
        if not cls.keys():
            return ConfigError(f"{cls.owner()}: unknown key {key!r}; {cls.owner()} has no parameters")
        return ConfigError(f"{cls.owner()}: unknown key {key!r}; valid keys: {', '.join(cls.keys())}")

    def with_overrides(self: P, overrides: Mapping[str, Any]) -> P:
        """A copy with fields replaced; string values are parsed by the field's type."""
        hints = typing.get_type_hints(type(self))
        changes: dict[str, Any] = {}
        for key, raw in overrides.items():
            if key not in hints or key not in self.keys():
                raise self._unknown_key(key)
            try:
                changes[key] = _parse(raw, hints[key]) if isinstance(raw, str) else raw
            except (TypeError, ValueError) as exc:
                raise ConfigError(
                    f"{self.owner()}: {key} must be {_type_name(hints[key])}, got {raw!r}"
                ) from exc
        return dataclasses.replace(self, **changes)


def claim(params_cls: type[Params], owner: str) -> None:
    """Give `params_cls` the registered name `owner` for its messages (first claim wins:
    an estimator subclass registered under a new name may reuse its parent's Params)."""
    if not params_cls.__dict__.get("_owner"):
        params_cls._owner = owner


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"a comma-separated list of {_type_name(typing.get_args(tp)[0])}"
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string",
            type(None): "none"}.get(tp, str(tp))


def _coerce(value: Any, tp: Any) -> Any:
    """Check `value` against the annotation and normalise (int → float, list → tuple)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in typing.get_args(tp):
            return None
        for arg in typing.get_args(tp):
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg)
            except (TypeError, ValueError):
                continue
        raise TypeError(value)
    if origin is typing.Literal:
        if value not in typing.get_args(tp):
            raise ValueError(value)
        return value
    if origin is tuple:
        item = typing.get_args(tp)[0]
        if not isinstance(value, (tuple, list)):
            raise TypeError(value)
        return tuple(_coerce(v, item) for v in value)
    if tp is bool:
        if not isinstance(value, bool):
            raise TypeError(value)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise TypeError(value)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(value)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise TypeError(value)
        return value
    return value


def _parse(text: str, tp: Any) -> Any:
    """Parse a command-line string by annotation: '5', '0.5', 'true', '0.01,15', 'none'."""
    text = text.strip()
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        if text.lower() in ("none", "null") and type(None) in typing.get_args(tp):
            return None
        for arg in typing.get_args(tp):
            if arg is type(None):
                continue
            try:
                return _parse(text, arg)
            except (TypeError, ValueError):
                continue
        raise ValueError(text)
    if origin is typing.Literal:
        return _coerce(text, tp)
    if origin is tuple:
        inner = text.strip("[]() ")
        parts = [p for p in inner.split(",") if p.strip()] if inner else []
        return tuple(_parse(p, typing.get_args(tp)[0]) for p in parts)
    if tp is bool:
        if text.lower() in ("true", "1", "yes", "on"):
            return True
        if text.lower() in ("false", "0", "no", "off"):
            return False
        raise ValueError(text)
    if tp is int:
        return int(text)
    if tp is float:
        return float(text)
    if tp is str:
        return text
    raise TypeError(tp)
