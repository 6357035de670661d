"""Scenario families (DESIGN §5) and their named presets.

A family is a module with a `Params` dataclass, `generate(params, rng) -> Recording`,
and named presets that reproduce a paper's setting; it registers them with
`cooploc.registry.register_scenario`. Each preset documents which figure it reproduces
and what the paper left unstated.

>>> from cooploc.scenarios import get_preset
>>> preset = get_preset("froehle2018")
>>> recording = preset.generate(np.random.default_rng(1))   # doctest: +SKIP
"""

from __future__ import annotations

from cooploc.registry import Preset, get_preset, presets, register_scenario

__all__ = ["Preset", "get_preset", "presets", "register_scenario"]
