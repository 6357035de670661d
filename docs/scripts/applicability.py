"""The "where each method runs" table, computed from the registry (run at site build).

For one preset of every scenario family, every registered estimator is constructed on a
short recording as `cooploc compare` decides it (`cooploc.compare.refusals`, i.e.
`cooploc.registry.construct`): a refusal gives the reason, an acceptance the measurement
kinds the estimator leaves aside (`cooploc.registry.unused_kinds`). Printed as a Markdown
page on stdout.
"""

from __future__ import annotations

import re

from cooploc.compare import refusals
from cooploc.config import ExperimentConfig
from cooploc.experiment import run_recording
from cooploc.registry import estimators, get_estimator, unused_kinds

#: one preset per family, its column title, and the overrides that keep generation short
FAMILIES = {
    "froehle2018": ("froehle2018", {"n_steps": 3}),
    "brambilla-crossroad": ("brambilla-*", {"n_steps": 3}),
    "sumo-grid-tlr": ("sumo-*", {"duration": 5.0, "warmup": 0.0}),
    "zhang2016-cv": ("zhang2016-*", {"n_steps": 3}),
    "gulati-2v": ("gulati-*", {"n_steps": 3}),
    "aoa-grid": ("aoa-grid", {}),
    "aoa-grid-tracking": ("aoa-grid-tracking", {"n_steps": 3}),
    "aoa-manhattan": ("aoa-manhattan", {}),
}


def cells(preset: str, overrides: dict) -> dict[str, str]:
    """Per registered estimator, its cell on `preset`: the refusal or what it leaves aside."""
    config = ExperimentConfig.build(preset, sorted(estimators()), scenario_overrides=overrides, runs=1,
                                    backend="serial")
    recording = run_recording(config, 0)
    refused = refusals(config, recording)
    out = {}
    for name in sorted(estimators()):
        if name in refused:
            out[name] = "**no**: " + _short(refused[name].removeprefix(f"{name} "))
        else:
            unused = unused_kinds(get_estimator(name), recording.setup)
            out[name] = "yes" + (f" (not {', '.join(unused)})" if unused else "")
    return out


def _short(reason: str) -> str:
    """The refusal in a table cell: what is missing, or what it reads and the scenario has."""
    reason = reason.split(" (it has")[0]
    reason = re.sub(r"needs the measurement kinds (.*), which this scenario does not have", r"needs \1",
                    reason)
    return re.sub(r"can use nothing this scenario offers: it reads (.*); the scenario has (.*)",
                  r"reads only \1; has \2", reason)


def table() -> str:
    columns = [cells(preset, over) for preset, (_, over) in FAMILIES.items()]
    lines = ["| estimator | " + " | ".join(title for title, _ in FAMILIES.values()) + " |",
             "| --- |" + " --- |" * len(FAMILIES)]
    for name in sorted(estimators()):
        lines.append(f"| `{name}` | " + " | ".join(column[name] for column in columns) + " |")
    return "\n".join(lines)


def page() -> str:
    return (
        "# Where each method runs\n\n"
        "Computed from the registry when this site is built: every estimator constructed on a "
        "short recording of one preset per scenario family, as `cooploc run` does. "
        "**no** gives the reason it is refused (a missing sensor, or nothing it can use); "
        "\"not X\" names the measurement kinds it runs without (`unused_kinds` in `summary.json`, "
        "and a line in `report.md`).\n\n" + table() + "\n"
    )


if __name__ == "__main__":
    print(page())
