"""`cooploc view`: one run of a results folder as an interactive, offline web page or an animation.

- `write_view(folder, run=0, out=None)`: one self-contained HTML file (Plotly, all
  JavaScript embedded) — the map with a time slider and play/pause, the RMSE over time
  beside it (`cooploc.view.figure`, `cooploc.view.page`).
- `write_animation(folder, run=0, out=None)`: the same scene as a GIF (matplotlib's
  Pillow writer) or an MP4 (its ffmpeg writer, where ffmpeg is installed)
  (`cooploc.view.animation`).

The pieces, one job each: `estimates` (what `cooploc run` keeps, ``estimates.parquet``),
`data` (reading a results folder, regenerating the recording), `scene` (roads,
infrastructure and static features per scenario family), `frames` (per-step drawing
data and the size limits), `figure`, `page`, `animation`.

Plotly, matplotlib, pyarrow and sumolib are imported inside the functions that use
them: importing this package costs nothing.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from cooploc.view.data import RunView

__all__ = ["VIEW_FILE", "link_in_report", "write_animation", "write_view"]

VIEW_FILE = "view.html"


def _meta(view: RunView) -> tuple[str, list[str]]:
    """The page's title and the lines under it."""
    cfg = view.config
    title = f"{cfg.scenario}: run {view.run} of {cfg.runs}, seed {cfg.seed}"
    lines = [view.recording.setup.description,
             "estimators: " + ", ".join(view.estimates) + ". Click a legend entry to hide or show it; "
             "hover a vehicle for its id, position error and NEES; 2σ ellipses around the estimates; "
             "red: truth, blue: prior, green: the first estimator."]
    if view.recomputed:
        lines.append(f"run {view.run}'s estimates are not in estimates.parquet: they were computed "
                     "again from config.toml (same seed, same numbers).")
    return title, lines


def write_view(folder: str | os.PathLike[str], run: int = 0,
               out: str | os.PathLike[str] | None = None) -> Path:
    """Write the interactive page of run `run` of a results folder (default
    ``FOLDER/view.html``) and return its path."""
    from cooploc.view.data import load_run
    from cooploc.view.figure import build_figure
    from cooploc.view.frames import frame_data
    from cooploc.view.page import write_page
    from cooploc.view.scene import scene

    view = load_run(folder, run)
    data = frame_data(view.recording, view.estimates, view.rmse)
    title, lines = _meta(view)
    fig = build_figure(scene(view.preset, view.config.scenario_params, view.recording), data)
    path = Path(out) if out is not None else Path(folder) / VIEW_FILE
    return write_page(fig, path, title, lines, data.notes)


def write_animation(folder: str | os.PathLike[str], run: int = 0,
                    out: str | os.PathLike[str] | None = None, fps: int = 8) -> Path:
    """Write run `run` as an animation: GIF, or MP4 if `out` ends in ``.mp4`` (needs ffmpeg);
    default ``FOLDER/view.gif``."""
    from cooploc.view.animation import animate
    from cooploc.view.data import load_run
    from cooploc.view.frames import frame_data
    from cooploc.view.scene import scene

    view = load_run(folder, run)
    data = frame_data(view.recording, view.estimates, view.rmse)
    title, _ = _meta(view)
    path = Path(out) if out is not None else Path(folder) / "view.gif"
    return animate(scene(view.preset, view.config.scenario_params, view.recording), data, title, path,
                   fps=fps)


def link_in_report(folder: str | os.PathLike[str], page: str = VIEW_FILE) -> None:
    """Add a link to the interactive page at the end of the folder's report.md (once)."""
    report = Path(folder) / "report.md"
    if not report.is_file():
        return
    text = report.read_text()
    line = f"Interactive view of run 0: [{page}]({page}) (open it in a browser; works offline)."
    if f"]({page})" not in text:
        report.write_text(text.rstrip("\n") + "\n\n" + line + "\n")
