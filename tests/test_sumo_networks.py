"""The user's own SUMO network (`--set network=PATH`) and the bounded traffic cache.

The OpenStreetMap extract is written by the test: a 3 × 3 block of residential streets
100 m apart with one signalised crossing, which SUMO's netconvert imports; each run is
a few seconds of SUMO on it. The cache tests use fake files where only sizes and times
matter, and the tiny grid where a real simulation is needed.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from cooploc.errors import ConfigError, InvalidInputError
from cooploc.scenarios import get_preset, sumo

_SHORT = {"duration": 6.0, "warmup": 15.0, "vehicle_period": 2.0, "pedestrian_period": 4.0,
          "max_static_features": 6, "zone_radii": (45.0, 90.0)}


def write_osm(path: Path, highway: str = "residential") -> Path:
    """A 3 × 3 grid of OSM nodes ~100 m apart (Berlin's latitude), joined by six ways."""
    lat0, lon0, dlat, dlon = 52.5, 13.4, 0.0009, 0.00148

    def node(r: int, c: int) -> int:
        return 1 + 3 * r + c

    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6">']
    for r in range(3):
        for c in range(3):
            signal = '<tag k="highway" v="traffic_signals"/>' if (r, c) == (1, 1) else ""
            lines.append(f'<node id="{node(r, c)}" lat="{lat0 + r * dlat:.7f}" '
                         f'lon="{lon0 + c * dlon:.7f}" version="1">{signal}</node>')
    rows = [[node(r, c) for c in range(3)] for r in range(3)]
    columns = [[node(r, c) for r in range(3)] for c in range(3)]
    for w, refs in enumerate(rows + columns):
        nds = "".join(f'<nd ref="{n}"/>' for n in refs)
        lines.append(f'<way id="{100 + w}" version="1">{nds}<tag k="highway" v="{highway}"/></way>')
    path.write_text("\n".join([*lines, "</osm>"]) + "\n")
    return path


@pytest.fixture()
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv(sumo.CACHE_LIMIT_VARIABLE, raising=False)
    return tmp_path / "cache" / "sumo"


def _params(network: str, **overrides: object) -> sumo.SumoParams:
    return get_preset("sumo-grid-tlr").params.with_overrides({"network": network, **_SHORT, **overrides})


# ----------------------------------------------------------------------------
# the user's own network
# ----------------------------------------------------------------------------


def test_an_openstreetmap_extract_is_converted_and_driven(cache: Path, tmp_path: Path) -> None:
    osm = write_osm(tmp_path / "town.osm")
    params = _params(str(osm))
    recording = sumo.generate(params, np.random.default_rng(0))
    assert str(osm) in recording.setup.description
    present = recording.truth.vehicle_present.sum(axis=1)
    assert present.min() > 0, "traffic on the imported streets at every step"
    assert any(len(f.links) for f in recording.frames)
    run = sumo.traffic(params, sumo.traffic_seed(params, np.random.default_rng(0)))
    assert run.signals.shape[0] >= 1, "the OSM traffic signal became a signalised junction"
    # the whole 200 m block lies inside the study area
    assert (np.diff(run.bounds, axis=1) > 150.0).all()
    # cached under the file's name, keyed by its content
    files = list(cache.glob("*.npz"))
    assert len(files) == 1 and files[0].name.startswith("own-town.osm-tlr-")
    key = sumo.cache_key(params, 1)
    osm.write_text(osm.read_text().replace("residential", "tertiary"))
    assert sumo.cache_key(params, 1) != key


def test_a_sumo_network_file_is_taken_as_it_is(cache: Path, tmp_path: Path) -> None:
    import subprocess

    import sumo as sumo_package

    net = tmp_path / "mine.net.xml"
    netgenerate = Path(sumo_package.SUMO_HOME) / "bin" / "netgenerate"
    subprocess.run([str(netgenerate), "--grid", "--grid.number", "3", "--grid.length", "90",
                    "--default.lanenumber", "1", "--sidewalks.guess", "true", "--no-warnings", "true",
                    "-o", str(net)], check=True, capture_output=True)
    recording = sumo.generate(_params(str(net), regulation="vsr"), np.random.default_rng(1))
    assert recording.truth.vehicle_present.any(axis=1).all()
    assert "mine.net.xml" in recording.setup.description


def test_a_network_without_walking_areas_gets_them_and_its_pedestrians_walk(cache: Path,
                                                                            tmp_path: Path) -> None:
    # a grid with sidewalks but neither crossings nor walking areas (like Braunschweig's
    # export): there SUMO lets a pedestrian jump over a junction in one step (5-17 m
    # here, up to 35 m on Braunschweig), a displacement its velocity cannot explain.
    # Cut with `PEDESTRIAN_OPTIONS`, every pedestrian step is a walk: it moves at most
    # 3 m/s × dt (SUMO's walking speeds stay below 2 m/s; the bends on walking areas
    # add a little), so it lands at most (3 + 2) m/s × dt from where its velocity takes
    # it (a turn on a walking area may reverse the heading within a step)
    import subprocess

    import sumo as sumo_package

    from cooploc.scenarios.sumo.simulation import PEDESTRIAN_OPTIONS

    net = tmp_path / "no-walking-areas.net.xml"
    netgenerate = Path(sumo_package.SUMO_HOME) / "bin" / "netgenerate"
    subprocess.run([str(netgenerate), "--grid", "--grid.number", "3", "--grid.length", "90",
                    "--default.lanenumber", "1", "--sidewalks.guess", "true", "--no-warnings", "true",
                    "-o", str(net)], check=True, capture_output=True)
    assert "walkingarea" not in net.read_text()
    params = _params(str(net), duration=30.0, pedestrian_period=1.0)
    run = sumo.traffic(params, 3)
    present = run.pedestrian_present[1:] & run.pedestrian_present[:-1]
    states = run.pedestrian_states
    step = np.diff(states[..., :2], axis=0)
    walked = np.linalg.norm(step, axis=2)[present]
    off_velocity = np.linalg.norm(step - states[1:, :, 2:] * params.dt, axis=2)[present]
    assert walked.size > 200 and np.linalg.norm(states[..., 2:], axis=2)[run.pedestrian_present].max() < 2.0
    assert walked.max() < 3.0 * params.dt
    assert off_velocity.max() < (3.0 + 2.0) * params.dt
    assert PEDESTRIAN_OPTIONS[-2:] == ("--walkingareas", "true")


@pytest.mark.parametrize(("name", "text", "what"), [
    ("missing.osm", None, "no such file"),
    ("broken.net.xml", "<net><edge id=", "not a readable SUMO network"),
    ("broken.osm", "this is not XML", "OpenStreetMap import"),
    ("footpaths.osm", "footway", "no road open to passenger cars"),
])
def test_a_bad_network_names_the_key_and_the_file(cache: Path, tmp_path: Path, name: str,
                                                 text: str | None, what: str) -> None:
    path = tmp_path / name
    if text == "footway":
        write_osm(path, highway="footway")
    elif text is not None:
        path.write_text(text)
    with pytest.raises(InvalidInputError, match=what) as info:
        sumo.generate(_params(str(path)), np.random.default_rng(0))
    assert f"network={str(path)!r}" in str(info.value)
    assert "\n" not in str(info.value)


def test_a_network_that_is_neither_a_name_nor_a_network_file_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"network must be .*\.net\.xml.*\.osm"):
        sumo.SumoParams(network="atlantis")


def test_the_city_preset_is_berlin_with_the_paper_sensors_and_dense_traffic() -> None:
    city, berlin = get_preset("sumo-berlin-city-tlr").params, get_preset("sumo-berlin-tlr").params
    assert (city.network, city.regulation, city.area_half_width) == ("berlin", "tlr", 2000.0)
    assert city.vehicle_period == 0.2 and city.pedestrian_period == 2.0
    # everything else, the sensors of §VI-A included, is sumo-berlin-tlr's
    assert city.with_overrides({k: getattr(berlin, k) for k in sumo.scenario.CITY}) == berlin


# ----------------------------------------------------------------------------
# the bounded cache
# ----------------------------------------------------------------------------


def _fake(folder: Path, name: str, size: int, used: float) -> Path:
    path = folder / name
    path.write_bytes(b"x" * size)
    os.utime(path, (used, used))
    return path


def test_evict_deletes_the_least_recently_used_files_first(tmp_path: Path) -> None:
    a, b, c = (_fake(tmp_path, f"{n}.npz", 100, t) for n, t in (("a", 3e8), ("b", 1e8), ("c", 2e8)))
    other = _fake(tmp_path, "notes.txt", 1000, 0.0)
    assert sumo.evict(tmp_path, 300) == []
    assert sumo.evict(tmp_path, 250) == [b]          # the oldest use goes first
    assert sumo.evict(tmp_path, 0, keep=c) == [a]    # never the file just written
    assert c.is_file() and other.is_file()          # and only cache files


@pytest.mark.parametrize(("text", "limit"), [("", sumo.DEFAULT_CACHE_LIMIT), ("1234", 1234),
                                             ("500M", 500 * 1024**2), ("1.5G", int(1.5 * 1024**3)),
                                             ("2gb", 2 * 1024**3), ("0", 0)])
def test_cache_limit_from_the_environment(monkeypatch: pytest.MonkeyPatch, text: str, limit: int) -> None:
    monkeypatch.setenv(sumo.CACHE_LIMIT_VARIABLE, text)
    assert sumo.cache_limit() == limit


def test_a_bad_cache_limit_names_the_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(sumo.CACHE_LIMIT_VARIABLE, "lots")
    with pytest.raises(ConfigError, match=f"{sumo.CACHE_LIMIT_VARIABLE}='lots'"):
        sumo.cache_limit()


def test_a_tiny_limit_keeps_only_the_newest_run_and_a_hit_counts_as_use(
        cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tiny = get_preset("sumo-grid-tlr").params.with_overrides(sumo.TINY_GRID)
    sumo.traffic(tiny, 1)
    first = sumo.cache_path(tiny, 1)
    os.utime(first, (1e8, 1e8))
    sumo.traffic(tiny, 1)  # a hit: used now
    assert first.stat().st_mtime > 1e9
    monkeypatch.setenv(sumo.CACHE_LIMIT_VARIABLE, str(first.stat().st_size + 10))
    sumo.traffic(tiny, 2)  # the folder would hold two runs: the least recently used goes
    assert sorted(cache.glob("*.npz")) == [sumo.cache_path(tiny, 2)]
