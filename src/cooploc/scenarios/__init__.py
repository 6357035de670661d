"""Scenario registry (DESIGN §5): families of generators and their named presets.

A family is a module with a `Params` dataclass and `generate(params, rng) -> Recording`.
A preset is a named parameter set of a family that reproduces a paper's setting; it
documents which figure it reproduces and what the paper left unstated.

>>> from cooploc.scenarios import get_preset
>>> preset = get_preset("froehle2018")
>>> recording = preset.generate(np.random.default_rng(1))   # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cooploc.errors import ConfigError
from cooploc.params import Params
from cooploc.types import Recording

__all__ = ["Preset", "get_preset", "presets"]


@dataclass(frozen=True)
class Preset:
    """A named scenario: family generator plus the parameters that reproduce a paper."""

    name: str
    params: Params
    generator: Callable[[Any, np.random.Generator], Recording]
    summary: str
    doc: str = ""

    def generate(self, rng: np.random.Generator, params: Params | None = None) -> Recording:
        """Simulate one run with `params` (default: the preset's own)."""
        return self.generator(self.params if params is None else params, rng)


def presets() -> dict[str, Preset]:
    """All presets by name."""
    from cooploc.scenarios import aoa_grid, brambilla2020, froehle2018, gulati, sumo, zhang2016

    found: dict[str, Preset] = {}
    for module in (froehle2018, brambilla2020, zhang2016, gulati, aoa_grid, sumo):
        for preset in module.PRESETS:
            found[preset.name] = preset
    return found


def get_preset(name: str) -> Preset:
    """The preset called `name`; `ConfigError` listing the known ones otherwise."""
    known = presets()
    if name not in known:
        raise ConfigError(f"unknown scenario {name!r}; known: {', '.join(sorted(known))}")
    return known[name]
