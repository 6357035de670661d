"""Every preset's recording saves and loads back identical (issue 16, item 2).

Radars of unlimited range (``max_range = inf``: zhang2016-*, gulati-*) are written as
the string "inf" in setup.json, which stays strict JSON. SUMO presets run on the tiny
generated grid of the SUMO tests (one network stands for all: the recording layout does
not depend on the network).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cooploc.io import load_recording, save_recording, validate_recording
from cooploc.registry import get_preset, presets
from cooploc.testing import preset_recording
from test_io import assert_same_recording

NON_SUMO = [name for name in presets() if not name.startswith("sumo-")]


@pytest.mark.parametrize("preset", NON_SUMO)
def test_every_preset_round_trips(preset: str, tmp_path: Path) -> None:
    recording = preset_recording(preset, 0, None if preset == "aoa-grid" else {"n_steps": 4})
    validate_recording(recording)
    save_recording(recording, tmp_path)
    json.loads((tmp_path / "setup.json").read_text(),
               parse_constant=lambda c: pytest.fail(f"setup.json holds {c}: not strict JSON"))
    assert_same_recording(recording, load_recording(tmp_path))


def test_infinite_radar_range_round_trips(tmp_path: Path) -> None:
    recording = preset_recording("gulati-2v", 0, {"n_steps": 2})
    assert recording.setup.sensors["radar"].max_range == np.inf
    save_recording(recording, tmp_path)
    assert json.loads((tmp_path / "setup.json").read_text())["sensors"]["radar"]["max_range"] == "inf"
    assert load_recording(tmp_path).setup.sensors["radar"].max_range == np.inf


def test_sumo_tiny_grid_round_trips(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from cooploc.scenarios import sumo

    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path / "cache"))
    preset = get_preset("sumo-grid-tlr")
    recording = preset.generate(np.random.default_rng(3), preset.params.with_overrides(sumo.TINY_GRID))
    validate_recording(recording)
    save_recording(recording, tmp_path / "rec")
    assert_same_recording(recording, load_recording(tmp_path / "rec"))
