"""Declarative parameters: frozen dataclasses with defaults, validation and overrides.

Scenario and estimator parameters subclass `Params`. A subclass lists its fields with
type hints and paper defaults, and checks values in `validate()` with `require`. Users
override fields from Python (`dataclasses.replace`), from TOML, or from the command
line (`with_overrides({"n_features": "5"})`), where strings are parsed by the field's
type; an unknown key or a bad value raises `ConfigError` that names the key and lists
the valid ones.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

from cooploc.errors import ConfigError

__all__ = ["Params", "require"]

P = TypeVar("P", bound="Params")


def require(condition: bool, owner: str, key: str, value: Any, must: str) -> None:
    """Raise `ConfigError("{owner}: {key} must {must}, got {value!r}")` unless condition."""
    if not condition:
        raise ConfigError(f"{owner}: {key} must {must}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class Params:
    """Base of every scenario and estimator parameter set."""

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
        self.validate()

    @classmethod
    def owner(cls) -> str:
        """Name used in error messages."""
        return cls.__qualname__

    def validate(self) -> None:
        """Check value ranges; subclasses override and call `require`."""

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
            raise ConfigError(
                f"{cls.owner()}: unknown key {unknown[0]!r}; valid keys: {', '.join(cls.keys())}"
            )
        return cls(**dict(data))

    def with_overrides(self: P, overrides: Mapping[str, Any]) -> P:
        """A copy with fields replaced; string values are parsed by the field's type."""
        hints = typing.get_type_hints(type(self))
        changes: dict[str, Any] = {}
        for key, raw in overrides.items():
            if key not in hints or key not in self.keys():
                raise ConfigError(
                    f"{self.owner()}: unknown key {key!r}; valid keys: {', '.join(self.keys())}"
                )
            try:
                changes[key] = _parse(raw, hints[key]) if isinstance(raw, str) else raw
            except (TypeError, ValueError) as exc:
                raise ConfigError(
                    f"{self.owner()}: {key} must be {_type_name(hints[key])}, got {raw!r}"
                ) from exc
        return dataclasses.replace(self, **changes)


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
        value = float(text)
        return value
    if tp is str:
        return text
    raise TypeError(tp)
