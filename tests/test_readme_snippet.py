"""The README's Python API snippet runs under the `spawn` start method (issue 16, item 7):
macOS, Windows and Linux from Python 3.14 start worker processes that import the script."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"

#: forces `spawn`, then runs the snippet as `__main__` (as `python snippet.py` would)
WRAPPER = """\
import multiprocessing, runpy, sys
multiprocessing.set_start_method("spawn", force=True)
runpy.run_path(sys.argv[1], run_name="__main__")
"""


def _snippet() -> str:
    blocks = [b for b in re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
              if "run_experiment" in b]
    assert len(blocks) == 1, "README should have one ```python block that runs an experiment"
    return blocks[0]


@pytest.mark.slow
def test_readme_api_snippet_runs_under_spawn(tmp_path):
    code = _snippet()
    # keep it fast: fewer runs; everything else as written (the default backend, processes)
    small = code.replace("runs=20", "runs=2")
    assert small != code, "the snippet no longer says runs=20; update this test"
    (tmp_path / "snippet.py").write_text(small)
    (tmp_path / "wrapper.py").write_text(WRAPPER)
    done = subprocess.run([sys.executable, "wrapper.py", "snippet.py"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "results" / "mine" / "summary.json").is_file()
