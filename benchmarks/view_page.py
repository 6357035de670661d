"""Size and load time of the `cooploc view` page, and the documentation's screenshots.

    python benchmarks/view_page.py                          # froehle2018 and sumo-berlin-tlr
    python benchmarks/view_page.py -p froehle2018 --screenshots docs/images
    python benchmarks/view_page.py --quick                  # froehle2018, 20 steps: checks the script

For each preset: one run (`cooploc run` with the estimators below, seed 1, serial),
then `write_view` (seconds to build the page), the HTML size, and the page in headless
Chromium: `load_seconds` is the wall-clock time of a Chromium process that loads the
file and dumps the DOM after the load event, minus the same for an empty page (the
browser's own start-up); `page_ms` is what the page itself reports at its load event
(``performance.now()``). With ``--screenshots DIR`` a PNG of the page (at the step
and zoom of `SETTINGS`) is written there (``view-PRESET.png``). Numbers depend on the machine and its
load; the JSON records the environment of `common.environment()`.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, write_json

#: what each preset is run with: estimators, scenario overrides, and the screenshot's
#: URL fragment (step, zoom box in m; `cooploc.view.page`)
SETTINGS: dict[str, tuple[list[str], dict, str]] = {
    "froehle2018": (["gnss-kf", "rsu-bp", "oracle-kf"], {}, "step=100&x=-60,200&y=-40,170"),
    "sumo-berlin-tlr": (["gnss-kf", "icp-da-lc"], {}, "step=200&x=1450,1950&y=750,1130"),
}


def _browser_seconds(page: Path) -> tuple[float, dict]:
    from cooploc.view.browser import load_page

    start = time.perf_counter()
    report = load_page(page, budget_ms=60000, timeout=600)
    return time.perf_counter() - start, {"status": report.status, "errors": report.errors}


def measure(name: str, folder: Path, quick: bool, screenshots: Path | None) -> dict:
    from cooploc.experiment import ExperimentConfig, run_experiment
    from cooploc.results import write_results
    from cooploc.view import write_view
    from cooploc.view.browser import screenshot

    estimators, overrides, fragment = SETTINGS.get(name, (["gnss-kf"], {}, "step=0"))
    if quick:
        estimators, overrides = ["gnss-kf", "oracle-kf"], {"n_steps": 20}
    cfg = ExperimentConfig.build(name, estimators, scenario_overrides=overrides, runs=1, seed=1,
                                 backend="serial")
    start = time.perf_counter()
    write_results(run_experiment(cfg), folder)
    run_seconds = time.perf_counter() - start
    start = time.perf_counter()
    page = write_view(folder)
    build_seconds = time.perf_counter() - start
    empty = folder / "empty.html"
    empty.write_text("<!DOCTYPE html><html><body><pre id='cooploc-errors'>[]</pre></body></html>")
    baseline, _ = _browser_seconds(empty)
    seconds, report = _browser_seconds(page)
    entry = {
        "estimators": estimators,
        "steps": cfg.scenario_params.n_steps,
        "run_seconds": run_seconds,
        "build_seconds": build_seconds,
        "html_bytes": page.stat().st_size,
        "load_seconds": seconds - baseline,
        "browser_start_seconds": baseline,
        "page_ms": report["status"].get("ms"),
        "frames": report["status"].get("frames"),
        "traces": len(report["status"].get("traces", [])),
        "javascript_errors": report["errors"],
    }
    if screenshots is not None:
        shot = folder / f"view-{name}.png"
        screenshot(page, shot, size=(1400, 900), budget_ms=60000, timeout=600, fragment=fragment)
        screenshots.mkdir(parents=True, exist_ok=True)
        (screenshots / shot.name).write_bytes(shot.read_bytes())
    return entry


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-p", "--preset", action="append",
                        help="preset (repeat) [froehle2018, sumo-berlin-tlr]")
    parser.add_argument("--quick", action="store_true", help="froehle2018, 20 steps")
    parser.add_argument("--screenshots", type=Path, default=None, help="write view-PRESET.png here")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "view_page.json")
    args = parser.parse_args(argv)

    names = ["froehle2018"] if args.quick else (args.preset or list(SETTINGS))
    results: dict = {**environment(), "presets": {}}
    with tempfile.TemporaryDirectory(prefix="cooploc-view-bench-") as tmp:
        for name in names:
            entry = measure(name, Path(tmp) / name, args.quick, args.screenshots)
            results["presets"][name] = entry
            print(f"{name:>18}: {entry['html_bytes'] / 1e6:5.1f} MB, {entry['frames']} frames, "
                  f"build {entry['build_seconds']:5.1f} s, load {entry['load_seconds']:5.2f} s "
                  f"(page {entry['page_ms']} ms), errors {entry['javascript_errors']}")
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
