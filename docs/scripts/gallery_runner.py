"""Run one gallery example and keep what it shows: its printed output and its figures.

Used by `gen_pages.py` (the site build) and by `tests/test_docs.py`. Each example runs
in its own Python process (as `__main__`, matplotlib's Agg backend, the repository's
`src` first on the path), so that examples cannot see each other's registrations;
every figure still open when it ends is saved as PNG.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples" / "gallery"

# runs inside the child process: argv = [example, figure folder]
_RUNNER = """
import runpy, sys
from pathlib import Path
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
example, out = Path(sys.argv[1]), Path(sys.argv[2])
runpy.run_path(str(example), run_name="__main__")
for i, num in enumerate(plt.get_fignums()):
    plt.figure(num).savefig(out / f"{example.stem}_{i}.png", dpi=100)
"""


@dataclass(frozen=True)
class Example:
    """One gallery script: its title and description (the module docstring) and code."""

    path: Path
    title: str
    description: str
    code: str

    @classmethod
    def read(cls, path: Path) -> Example:
        source = path.read_text(encoding="utf-8")
        module = ast.parse(source)
        doc = ast.get_docstring(module)
        if not doc:
            raise ValueError(f"{path}: a gallery example starts with a docstring (title, description)")
        title, _, description = doc.partition("\n")
        body = module.body[0]
        code = "\n".join(source.splitlines()[body.end_lineno:]).strip("\n")
        return cls(path, title.strip().rstrip("."), description.strip(), code)


def examples() -> list[Example]:
    """Every gallery example, in file-name order."""
    return [Example.read(p) for p in sorted(EXAMPLES.glob("*.py"))]


def _env() -> dict[str, str]:
    env = dict(os.environ, MPLBACKEND="Agg")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT / "src"), env.get("PYTHONPATH")) if p)
    return env


def run_script(path: Path, args: list[str], timeout: float = 600) -> str:
    """Run a Python script with the repository's `src` first; return its standard output.

    Raises `RuntimeError` with the script's standard error when it fails.
    """
    done = subprocess.run([sys.executable, str(path), *args], capture_output=True, text=True,
                          env=_env(), timeout=timeout, cwd=ROOT)
    if done.returncode != 0:
        raise RuntimeError(f"{path.name} failed:\n{done.stderr}")
    return done.stdout


def run_example(path: Path, figures: Path, timeout: float = 300) -> tuple[str, list[Path]]:
    """Run gallery example `path`; return its standard output and its figures' PNG files.

    Raises `RuntimeError` with the example's standard error when it fails.
    """
    figures.mkdir(parents=True, exist_ok=True)
    done = subprocess.run([sys.executable, "-c", _RUNNER, str(path), str(figures)],
                          capture_output=True, text=True, env=_env(), timeout=timeout, cwd=figures)
    if done.returncode != 0:
        raise RuntimeError(f"gallery example {path.name} failed:\n{done.stderr}")
    return done.stdout, sorted(figures.glob(f"{path.stem}_*.png"))
