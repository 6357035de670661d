"""Pages and figures made when the site is built (run by mkdocs-gen-files).

- `gallery/`: every `examples/gallery/*.py` is run; each becomes `gallery/<name>.md` — its
  description, its figures, its code and what it printed — with a download of the
  script, and `gallery/index.md` shows every example's first figure.
- `scenarios/<preset>.png`: one run of a preset of every scenario family, drawn by
  `scenario_figures.py`, for `scenarios.md`.
- `applicability.md`: which estimator runs on which scenario family, and what it leaves
  aside, computed from the registry by `applicability.py`.

Everything runs in child processes (examples cannot see each other's registrations;
SUMO keeps global state), two at a time — the scenario figures, the longest job, first.
A failing example or figure fails the build.
"""

from __future__ import annotations

import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import mkdocs_gen_files

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gallery_runner import Example, examples, run_example, run_script

SCENARIO_FIGURES = Path(__file__).resolve().parent / "scenario_figures.py"
APPLICABILITY = Path(__file__).resolve().parent / "applicability.py"


def gallery_page(example: Example, output: str, figures: list[Path]) -> str:
    name = example.path.stem
    lines = [f"# {example.title}", "", example.description, ""]
    lines += [f"![{example.title}, figure {i + 1}]({fig.name})" for i, fig in enumerate(figures)]
    lines += ["", "```python", example.code, "```", ""]
    if output.strip():
        lines += ["Output:", "", "```text", output.rstrip(), "```", ""]
    lines += [f"[Download `{name}.py`]({name}.py) · run it with `python {name}.py`", ""]
    return "\n".join(lines)


def gallery_index(found: list[Example], first_figures: list[Path | None]) -> str:
    cards = []
    for example, fig in zip(found, first_figures, strict=True):
        name = example.path.stem
        thumb = f"![]({fig.name})" if fig is not None else ""
        cards.append(f'<figure markdown="span">\n[{thumb}]({name}.md)\n'
                     f'<figcaption markdown="span">[{example.title}]({name}.md)</figcaption>\n</figure>')
    return ("# Gallery\n\nRunnable examples, each a script in `examples/gallery/`. They run when "
            "the site is built, so every figure and every printed number below is what the code "
            "on its page makes today (`tests/test_docs.py` runs them too).\n\n"
            '<div class="gallery-grid" markdown>\n\n' + "\n\n".join(cards) + "\n\n</div>\n")


def write(path: str, data: bytes | str) -> None:
    with mkdocs_gen_files.open(path, "wb" if isinstance(data, bytes) else "w") as f:
        f.write(data)


def main() -> None:
    found = examples()
    with tempfile.TemporaryDirectory(prefix="cooploc-docs-") as tmp:
        scenario_dir, gallery_dir = Path(tmp, "scenarios"), Path(tmp, "gallery")
        scenario_dir.mkdir()
        with ThreadPoolExecutor(max_workers=2) as pool:
            scenarios = pool.submit(run_script, SCENARIO_FIGURES, [str(scenario_dir)])
            applicability = pool.submit(run_script, APPLICABILITY, [])
            runs = [pool.submit(run_example, ex.path, gallery_dir) for ex in found]
            scenarios.result()
            results = [r.result() for r in runs]
        write("applicability.md", applicability.result())
        for png in sorted(scenario_dir.glob("*.png")):
            write(f"scenarios/{png.name}", png.read_bytes())
        for example, (output, figures) in zip(found, results, strict=True):
            name = example.path.stem
            for fig in figures:
                write(f"gallery/{fig.name}", fig.read_bytes())
            write(f"gallery/{name}.py", example.path.read_text(encoding="utf-8"))
            write(f"gallery/{name}.md", gallery_page(example, output, figures))
        write("gallery/index.md", gallery_index(found, [figs[0] if figs else None for _, figs in results]))


main()
