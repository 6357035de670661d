"""The viewer's scene as an animation for slides and papers: GIF, or MP4 where ffmpeg exists.

The same `Scene` and `FrameData` as the interactive page, drawn with matplotlib (Agg)
and written by matplotlib's animation writers: `PillowWriter` for ``.gif`` (Pillow
comes with matplotlib, so GIFs need nothing more), `FFMpegWriter` for ``.mp4`` when
an ``ffmpeg`` binary is on the path. Left the map, right the RMSE over time with a
cursor; truth red, prior blue, the first estimator green. At most
`MAX_ANIMATION_FRAMES` frames are drawn (every s-th frame of the page's above that),
which keeps a GIF to a few megabytes.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.view.figure import PRIOR_COLOUR, TRUTH_COLOUR, estimator_colour
from cooploc.view.frames import FrameData
from cooploc.view.scene import Scene

__all__ = ["MAX_ANIMATION_FRAMES", "animate"]

MAX_ANIMATION_FRAMES = 100
_EMPTY = np.zeros((0, 2))


def _limits(scene: Scene, data: FrameData) -> tuple[tuple[float, float], tuple[float, float]]:
    parts = [scene.roads, scene.infrastructure[:, :2], *data.truth_xy]
    pts = np.concatenate([p.reshape(-1, 2) for p in parts])
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return (-1.0, 1.0), (-1.0, 1.0)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * max(float((hi - lo).max()), 10.0)
    return (lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad)


def _writer(path: Path, fps: int) -> Any:
    from matplotlib import animation

    suffix = path.suffix.lower()
    if suffix == ".gif":
        return animation.PillowWriter(fps=fps)
    if suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise InvalidInputError(f"--out {path}: an MP4 needs ffmpeg on the PATH; write a .gif instead")
        return animation.FFMpegWriter(fps=fps, bitrate=2400)
    raise InvalidInputError(f"--out {path}: an animation is a .gif or an .mp4, got {suffix or 'no suffix'!r}")


def animate(scene: Scene, data: FrameData, title: str, path: str | os.PathLike[str], fps: int = 8,
            dpi: int = 90) -> Path:
    """Write the run as an animation at `path` (.gif or .mp4) and return the path."""
    from matplotlib import animation

    from cooploc.plots import pyplot

    out = Path(path)
    writer = _writer(out, fps)
    plt = pyplot()
    fig, (ax, ax_rmse) = plt.subplots(1, 2, figsize=(11, 5.2), gridspec_kw={"width_ratios": [1.6, 1]})
    fig.suptitle(title, fontsize=11)
    if len(scene.junctions):
        ax.plot(*scene.junctions.T, color="#d0d0d0", lw=0.6)
    if len(scene.roads):
        ax.plot(*scene.roads.T, color="#b8b8b8", lw=0.9)
    if len(scene.paths):
        ax.plot(*scene.paths.T, color=TRUTH_COLOUR, lw=0.7, alpha=0.18)
    if len(scene.infrastructure):
        ax.plot(*scene.infrastructure[:, :2].T, "k^", ms=6, label="infrastructure")
    if len(scene.static_ids):
        ax.plot(*scene.static_positions.T, "s", mfc="none", color=TRUTH_COLOUR, ms=5, label="static features")
    truth, = ax.plot([], [], "o", color=TRUTH_COLOUR, ms=4, label="truth")
    features, = ax.plot([], [], "D", mfc="none", color=TRUTH_COLOUR, ms=5)
    prior, = ax.plot([], [], "o", color=PRIOR_COLOUR, ms=3, label="prior (step 0)")
    prior_ell, = ax.plot([], [], color=PRIOR_COLOUR, lw=0.7)
    links, = ax.plot([], [], color="0.5", lw=0.5, alpha=0.4)
    detections, = ax.plot([], [], color=TRUTH_COLOUR, lw=0.5, ls=":", alpha=0.5)
    layers = []
    for j, (name, layer) in enumerate(data.layers.items()):
        colour = estimator_colour(j)
        artists = [ax.plot([], [], "x", color=colour, ms=4, label=name)[0],
                   ax.plot([], [], color=colour, lw=0.7)[0],
                   ax.plot([], [], "D", color=colour, ms=4)[0],
                   ax.plot([], [], color=colour, lw=0.6, ls=":")[0],
                   ax.plot([], [], color=colour, lw=0.6)[0],
                   ax.plot([], [], color=colour, lw=1.2, ls=":")[0]]
        layers.append((layer, artists))
        if name in data.rmse:
            t, r = data.rmse[name]
            ax_rmse.plot(t, r, color=colour, lw=1, label=name)
    cursor = ax_rmse.axvline(data.t[0] if len(data.t) else 0.0, color="k", ls="--", lw=0.8)
    (x0, x1), (y0, y1) = _limits(scene, data)
    ax.set(xlim=(x0, x1), ylim=(y0, y1), xlabel="x [m]", ylabel="y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="lower right", fontsize=7, framealpha=0.8)
    ax_rmse.set(xlabel="time [s]", ylabel="position RMSE [m]")
    ax_rmse.set_ylim(bottom=0)
    ax_rmse.grid(alpha=0.3)
    clock = ax.text(0.01, 0.99, "", transform=ax.transAxes, va="top", fontsize=9)
    fig.tight_layout()

    shown = np.arange(0, len(data.steps), max(1, int(np.ceil(len(data.steps) / MAX_ANIMATION_FRAMES))))

    def draw(i: int) -> list[Any]:
        truth.set_data(*data.truth_xy[i].reshape(-1, 2).T)
        features.set_data(*data.feature_xy[i].reshape(-1, 2).T)
        prior.set_data(*(data.prior_xy if i == 0 else _EMPTY).T)
        prior_ell.set_data(*(data.prior_ellipses if i == 0 else _EMPTY).T)
        links.set_data(*data.links[i].reshape(-1, 2).T)
        detections.set_data(*data.detections[i].reshape(-1, 2).T)
        for layer, (marks, ell, fmarks, fell, right, wrong) in layers:
            marks.set_data(*layer.xy[i].reshape(-1, 2).T)
            ell.set_data(*layer.ellipses[i].reshape(-1, 2).T)
            fmarks.set_data(*layer.feature_xy[i].reshape(-1, 2).T)
            fell.set_data(*layer.feature_ellipses[i].reshape(-1, 2).T)
            right.set_data(*layer.right[i].reshape(-1, 2).T)
            wrong.set_data(*layer.wrong[i].reshape(-1, 2).T)
        cursor.set_xdata([data.t[i], data.t[i]])
        clock.set_text(f"t = {data.t[i]:.1f} s (step {int(data.steps[i])})")
        return []

    movie = animation.FuncAnimation(fig, draw, frames=[int(i) for i in shown], blit=False)
    out.parent.mkdir(parents=True, exist_ok=True)
    movie.save(str(out), writer=writer, dpi=dpi)
    plt.close(fig)
    return out
