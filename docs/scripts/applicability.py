"""The "where each method runs" table, computed from the registry (run at site build).

For one preset of every scenario family, every registered estimator is constructed on a
short recording exactly as the runner does (`cooploc.registry.construct`): a refusal
gives the reason, an acceptance the measurement kinds the estimator leaves aside
(`cooploc.registry.unused_kinds`). Printed as a Markdown page on stdout.
"""

from __future__ import annotations

import re

import numpy as np

import cooploc
from cooploc.errors import ConfigError
from cooploc.registry import construct, estimators, get_estimator, unused_kinds

#: one preset per family, its column title, and the overrides that keep generation short
FAMILIES = {
    "froehle2018": ("froehle2018", {"n_steps": 3}),
    "brambilla-crossroad": ("brambilla-*", {"n_steps": 3}),
    "sumo-grid-tlr": ("sumo-*", {"duration": 5.0, "warmup": 0.0}),
    "zhang2016-cv": ("zhang2016-*", {"n_steps": 3}),
    "gulati-2v": ("gulati-*", {"n_steps": 3}),
    "aoa-grid": ("aoa-grid", {}),
    "aoa-grid-tracking": ("aoa-grid-tracking", {"n_steps": 3}),
}


def cell(name: str, recording: cooploc.Recording) -> str:
    cls = get_estimator(name)
    try:
        construct(cls, recording.setup, None, np.random.default_rng(0), recording.truth)
    except ConfigError as exc:
        return "**no**: " + _short(str(exc).removeprefix(f"{name} "))
    unused = unused_kinds(cls, recording.setup)
    return "yes" + (f" (not {', '.join(unused)})" if unused else "")


def _short(reason: str) -> str:
    """The refusal in a table cell: what is missing, or what it reads and the scenario has."""
    reason = reason.split(" (it has")[0]
    reason = re.sub(r"needs the measurement kinds (.*), which this scenario does not have", r"needs \1",
                    reason)
    return re.sub(r"can use nothing this scenario offers: it reads (.*); the scenario has (.*)",
                  r"reads only \1; has \2", reason)


def table() -> str:
    recordings = {preset: cooploc.get_preset(preset).generate(
        np.random.default_rng(0), cooploc.get_preset(preset).params.with_overrides(over))
        for preset, (_, over) in FAMILIES.items()}
    lines = ["| estimator | " + " | ".join(title for title, _ in FAMILIES.values()) + " |",
             "| --- |" + " --- |" * len(FAMILIES)]
    for name in sorted(estimators()):
        lines.append(f"| `{name}` | " + " | ".join(cell(name, r) for r in recordings.values()) + " |")
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
