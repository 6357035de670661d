"""The documentation site: every gallery example runs and shows a figure, and every page
that mkdocs.yml names exists (written, or made at build time by docs/scripts/gen_pages.py).

The strict build itself (`mkdocs build --strict`, ≈ 30 s of CPU) runs in `.ci/run`, not
here: it needs the `docs` extra, and it runs every example again.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

import cooploc

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "scripts"))

from gallery_runner import EXAMPLES, Example, examples, run_example  # noqa: E402


def _nav_pages() -> list[str]:
    """The .md files named in the nav of mkdocs.yml (read as text: no YAML dependency)."""
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = text[text.index("\nnav:"):]
    return re.findall(r"([\w./-]+\.md)\s*$", nav, flags=re.MULTILINE)


def _generated_pages() -> set[str]:
    """Pages that gen_pages.py writes: the gallery index, one page per example, the
    applicability table."""
    return ({"gallery/index.md", "applicability.md"}
            | {f"gallery/{p.stem}.md" for p in EXAMPLES.glob("*.py")})


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.py")), ids=lambda p: p.stem)
def test_gallery_example_runs_and_draws(path: Path, tmp_path: Path) -> None:
    example = Example.read(path)
    assert example.title and example.description, f"{path.name}: docstring needs a title and a description"
    output, figures = run_example(path, tmp_path)
    assert figures, f"{path.name} left no matplotlib figure open"
    assert all(f.stat().st_size > 5_000 for f in figures), "a figure is (nearly) empty"
    assert output.strip(), f"{path.name} printed nothing"


def test_every_nav_page_exists() -> None:
    pages = _nav_pages()
    assert "index.md" in pages and "reference/index.md" in pages   # the parser found the nav
    generated = _generated_pages()
    missing = [p for p in pages if p not in generated and not (DOCS / p).is_file()]
    assert not missing, f"mkdocs.yml names pages that do not exist: {missing}"


def test_every_gallery_example_is_in_the_nav() -> None:
    # mkdocs --strict refuses pages outside the nav; say which example it is here already
    pages = set(_nav_pages())
    assert {f"gallery/{e.path.stem}.md" for e in examples()} <= pages


def test_every_markdown_page_is_in_the_nav() -> None:
    pages = set(_nav_pages())
    written = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md") if "scripts" not in p.parts}
    assert written <= pages, f"pages outside the nav: {sorted(written - pages)}"


def test_scenario_figures_name_registered_presets_and_appear_on_the_page() -> None:
    from scenario_figures import FIGURES

    assert set(FIGURES) <= set(cooploc.presets())
    page = (DOCS / "scenarios.md").read_text(encoding="utf-8")
    shown = set(re.findall(r"\(scenarios/([\w-]+)\.png\)", page))
    assert shown == set(FIGURES)


def test_the_applicability_page_is_computed_from_the_registry() -> None:
    """docs/scripts/applicability.py: one row per registered estimator, refusals give a
    reason, and a known case of each kind reads as the registry decides."""
    from applicability import FAMILIES, page

    from cooploc.registry import estimators

    text = page()
    rows = [line for line in text.splitlines() if line.startswith("| `")]
    assert len(rows) == len(estimators())
    cells = {row.split("|")[1].strip(" `"): [c.strip() for c in row.split("|")[2:-1]] for row in rows}
    assert all(len(c) == len(FAMILIES) for c in cells.values())
    column = {preset: i for i, preset in enumerate(FAMILIES)}
    assert cells["gnss-kf"][column["zhang2016-cv"]].startswith("**no**: reads only gnss (gnss-position)")
    assert cells["gnss-kf"][column["froehle2018"]] == "yes (not v2f)"
    assert cells["oracle-kf"][column["froehle2018"]] == "yes"
    assert cells["plbp"][column["froehle2018"]] == "**no**: needs aoa"
