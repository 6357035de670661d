"""The Plotly figure of a run: the map with a time slider, and the RMSE over time beside it.

Left, the map (equal axes, metres): the static `Scene` (roads, junctions, faint true
paths of open-plane scenarios, infrastructure, static features), then per frame the
true vehicles and moving features (red), the step-0 prior (blue), the V2V links and
V2F detections of the step (detections off until clicked in the legend), each
estimator's means with 2-σ ellipses (the first estimator green, as true / prior /
estimate are red, blue, green in the AoA paper), its feature estimates, and the
associations it decided (measuring vehicle → measured point → the feature it was
given; solid: right, dotted: wrong). Right, each estimator's position RMSE over the
vehicles at every step of the run (``errors.parquet``) with a cursor at the shown
step.

Plotly frames carry only the traces that change; the slider and the play/pause
buttons step through them without redrawing the scene. Every estimator is one legend
group (markers, ellipses, features and its RMSE curve toggle together); links and
each estimator's associations are groups of their own, so they toggle apart.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cooploc.errors import ConfigError
from cooploc.view.frames import FrameData
from cooploc.view.scene import Scene

__all__ = ["ESTIMATOR_COLOURS", "PRIOR_COLOUR", "TRUTH_COLOUR", "build_figure"]

TRUTH_COLOUR = "#d62728"  # red: true positions (AoA paper)
PRIOR_COLOUR = "#1f77b4"  # blue: prior
#: the first estimator green (the AoA paper's estimate), then colours unlike red and blue
ESTIMATOR_COLOURS = ("#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22",
                     "#7f7f7f")
_ROAD = "#b8b8b8"


def estimator_colour(i: int) -> str:
    return ESTIMATOR_COLOURS[i % len(ESTIMATOR_COLOURS)]


def _f32(xy: np.ndarray, axis: int) -> np.ndarray:
    # float32 halves the embedded data; centimetres survive it for maps of a few km
    return np.asarray(xy, dtype=np.float32).reshape(-1, 2)[:, axis]


def _xy(xy: np.ndarray) -> dict[str, np.ndarray]:
    xy = np.asarray(xy).reshape(-1, 2)
    if not len(xy):  # one NaN point: plotly leaves a trace without data out of the legend
        xy = np.full((1, 2), np.nan)
    return {"x": _f32(xy, 0), "y": _f32(xy, 1)}


def _bounds(scene: Scene, data: FrameData) -> tuple[list[float], list[float]]:
    # the vehicles and the roads set the view; features may wander off (zoom out to follow)
    parts = [scene.roads, scene.infrastructure[:, :2], *data.truth_xy]
    pts = np.concatenate([p.reshape(-1, 2) for p in parts])
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return [-1.0, 1.0], [-1.0, 1.0]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * max(float((hi - lo).max()), 10.0)
    return [float(lo[0] - pad), float(hi[0] + pad)], [float(lo[1] - pad), float(hi[1] + pad)]


def _dynamic(data: FrameData, i: int) -> list[dict[str, Any]]:
    """The data of every per-frame trace at frame i, in trace order (see `build_figure`)."""
    out: list[dict[str, Any]] = []
    if len(data.prior_xy):
        first = i == 0
        out.append(_xy(data.prior_xy if first else np.zeros((0, 2))))
        out.append(_xy(data.prior_ellipses if first else np.zeros((0, 2))))
    if any(len(link) for link in data.links):
        out.append(_xy(data.links[i]))
    if any(len(d) for d in data.detections):
        out.append(_xy(data.detections[i]))
    for layer in data.layers.values():
        custom = np.stack([layer.ids[i], np.round(layer.error[i], 3), np.round(layer.nees[i], 3)],
                          axis=1) if len(layer.ids[i]) else np.zeros((0, 3))
        out.append({**_xy(layer.xy[i]), "customdata": custom})
        out.append(_xy(layer.ellipses[i]))
        if layer.has_features:
            out.append({**_xy(layer.feature_xy[i]), "customdata": layer.feature_ids[i]})
            out.append(_xy(layer.feature_ellipses[i]))
        if layer.has_association:
            out.append(_xy(layer.right[i]))
            out.append(_xy(layer.wrong[i]))
    # the truth last, on top: a red dot inside each estimate's cross
    out.append({**_xy(data.truth_xy[i]), "customdata": data.truth_ids[i]})
    if any(len(f) for f in data.feature_xy):
        out.append({**_xy(data.feature_xy[i]), "customdata": data.feature_ids[i]})
    if data.rmse:
        top = max((float(np.nanmax(r)) for _, r in data.rmse.values() if len(r)), default=1.0)
        out.append({"x": [data.t[i], data.t[i]], "y": [0.0, top * 1.05]})
    return out


def _dynamic_styles(data: FrameData) -> list[dict[str, Any]]:
    """Name, legend group and style of every per-frame trace, in trace order."""
    styles: list[dict[str, Any]] = []
    if len(data.prior_xy):
        styles.append(dict(name="prior (step 0)", mode="markers", legendgroup="prior",
                           marker={"color": PRIOR_COLOUR, "size": 6}, hoverinfo="skip"))
        styles.append(dict(name="prior 2σ", mode="lines", legendgroup="prior", showlegend=False,
                           line={"color": PRIOR_COLOUR, "width": 1}, hoverinfo="skip"))
    if any(len(link) for link in data.links):
        styles.append(dict(name="V2V links", mode="lines", legendgroup="links",
                           line={"color": "rgba(120,120,120,0.35)", "width": 1}, hoverinfo="skip"))
    if any(len(d) for d in data.detections):
        # off at first (click the legend): with many detections they hide the map
        styles.append(dict(name="V2F detections", mode="lines", legendgroup="detections",
                           visible="legendonly", hoverinfo="skip",
                           line={"color": "rgba(214,39,40,0.5)", "width": 1, "dash": "dot"}))
    for j, (name, layer) in enumerate(data.layers.items()):
        colour = estimator_colour(j)
        styles.append(dict(
            name=name, mode="markers", legendgroup=name,
            marker={"color": colour, "size": 9, "symbol": "x-thin", "line": {"width": 2, "color": colour}},
            hovertemplate=(f"<b>{name}</b><br>vehicle %{{customdata[0]}}<br>error "
                           "%{customdata[1]:.2f} m<br>NEES %{customdata[2]:.2f}<extra></extra>")))
        styles.append(dict(name=f"{name} 2σ", mode="lines", legendgroup=name, showlegend=False,
                           line={"color": colour, "width": 1}, hoverinfo="skip"))
        if layer.has_features:
            styles.append(dict(name=f"{name} features", mode="markers", legendgroup=name,
                               showlegend=False, marker={"color": colour, "size": 7,
                                                         "symbol": "diamond"},
                               hovertemplate=f"{name}: feature %{{customdata}}<extra></extra>"))
            styles.append(dict(name=f"{name} features 2σ", mode="lines", legendgroup=name,
                               showlegend=False, line={"color": colour, "width": 1, "dash": "dot"},
                               hoverinfo="skip"))
        if layer.has_association:
            styles.append(dict(name=f"{name}: association", mode="lines",
                               legendgroup=f"association {name}",
                               line={"color": colour, "width": 1}, hoverinfo="skip"))
            styles.append(dict(name=f"{name}: wrong association", mode="lines",
                               legendgroup=f"association {name}", showlegend=False,
                               line={"color": colour, "width": 2, "dash": "dot"}, hoverinfo="skip"))
    styles.append(dict(name="truth", mode="markers", legendgroup="truth",
                       marker={"color": TRUTH_COLOUR, "size": 5, "symbol": "circle"},
                       hovertemplate="true vehicle %{customdata}<extra></extra>"))
    if any(len(f) for f in data.feature_xy):
        styles.append(dict(name="true features", mode="markers", legendgroup="truth-features",
                           marker={"color": TRUTH_COLOUR, "size": 8, "symbol": "diamond-open"},
                           hovertemplate="true feature %{customdata}<extra></extra>"))
    if data.rmse:
        styles.append(dict(name="shown step", mode="lines", showlegend=False, xaxis="x2", yaxis="y2",
                           line={"color": "black", "width": 1, "dash": "dash"}, hoverinfo="skip"))
    return styles


def plotly_objects() -> Any:
    """`plotly.graph_objects`, or a one-line error naming the extra that installs it."""
    try:
        import plotly.graph_objects as go
    except ImportError as exc:
        raise ConfigError("cooploc view needs Plotly: pip install 'cooploc[view]' "
                          f"(import failed: {exc})") from None
    return go


def _static_traces(scene: Scene, data: FrameData) -> list[Any]:
    go = plotly_objects()

    traces = []
    if len(scene.junctions):
        traces.append(go.Scatter(name="junctions", **_xy(scene.junctions), mode="lines", fill="toself",
                                 fillcolor="#e4e4e4", line={"color": "#d0d0d0", "width": 0.5},
                                 hoverinfo="skip", showlegend=False))
    if len(scene.roads):
        traces.append(go.Scatter(name="roads", **_xy(scene.roads), mode="lines", hoverinfo="skip",
                                 line={"color": _ROAD, "width": 1.5}))
    if len(scene.paths):
        traces.append(go.Scatter(name="true paths", **_xy(scene.paths), mode="lines", hoverinfo="skip",
                                 line={"color": "rgba(214,39,40,0.18)", "width": 1}))
    if len(scene.infrastructure):
        traces.append(go.Scatter(name="infrastructure", **_xy(scene.infrastructure[:, :2]),
                                 mode="markers", text=list(scene.infrastructure_labels),
                                 marker={"color": "black", "size": 9, "symbol": "triangle-up"},
                                 hovertemplate="%{text}<extra></extra>"))
    if len(scene.static_ids):
        traces.append(go.Scatter(name="static features", **_xy(scene.static_positions), mode="markers",
                                 customdata=scene.static_ids,
                                 marker={"color": TRUTH_COLOUR, "size": 7, "symbol": "square-open"},
                                 hovertemplate="static feature %{customdata}<extra></extra>"))
    for j, (name, (t, r)) in enumerate(data.rmse.items()):
        if name not in data.layers:
            continue
        colour = estimator_colour(list(data.layers).index(name)) if name in data.layers else None
        traces.append(go.Scatter(name=f"{name} RMSE", x=np.asarray(t, np.float32),
                                 y=np.asarray(r, np.float32), legendgroup=name,
                                 mode="lines" if len(t) > 1 else "markers",  # a snapshot: one point
                                 showlegend=False, xaxis="x2", yaxis="y2",
                                 line={"color": colour or estimator_colour(j), "width": 1.5},
                                 hovertemplate=f"{name}: %{{y:.2f}} m at %{{x:.2f}} s<extra></extra>"))
    return traces


def build_figure(scene: Scene, data: FrameData) -> Any:
    """The interactive figure (`plotly.graph_objects.Figure`) of a run."""
    go = plotly_objects()

    static = _static_traces(scene, data)
    styles = _dynamic_styles(data)
    first = _dynamic(data, 0)
    dynamic = [go.Scatter(**style, **values) for style, values in zip(styles, first, strict=True)]
    fig = go.Figure(data=static + dynamic)
    indices = list(range(len(static), len(static) + len(dynamic)))
    fig.frames = [go.Frame(name=str(int(k)), traces=indices,
                           data=[go.Scatter(**values) for values in _dynamic(data, i)])
                  for i, k in enumerate(data.steps)]
    x_range, y_range = _bounds(scene, data)
    play = {"frame": {"duration": 120, "redraw": False}, "fromcurrent": True,
            "transition": {"duration": 0}, "mode": "immediate"}
    pause = {"frame": {"duration": 0, "redraw": False}, "mode": "immediate", "transition": {"duration": 0}}
    slider_steps = [{"label": f"{t:.1f}", "method": "animate",
                     "args": [[str(int(k))], pause]} for k, t in zip(data.steps, data.t, strict=True)]
    fig.update_layout(
        template="plotly_white",
        margin={"l": 50, "r": 20, "t": 30, "b": 40},
        hovermode="closest",
        legend={"orientation": "h", "y": -0.2, "x": 0.0, "groupclick": "togglegroup"},
        xaxis={"domain": [0.0, 0.64], "range": x_range, "title": "x [m]", "constrain": "domain"},
        yaxis={"range": y_range, "title": "y [m]", "scaleanchor": "x", "scaleratio": 1},
        xaxis2={"domain": [0.72, 1.0], "anchor": "y2", "title": "time [s]"},
        yaxis2={"domain": [0.3, 1.0], "anchor": "x2", "title": "position RMSE [m]", "rangemode": "tozero"},
        updatemenus=[{"type": "buttons", "direction": "left", "x": 0.0, "y": -0.06, "xanchor": "left",
                      "yanchor": "top", "pad": {"t": 0, "r": 10}, "showactive": False,
                      "buttons": [{"label": "▶ play", "method": "animate", "args": [None, play]},
                                  {"label": "❚❚ pause", "method": "animate",
                                   "args": [[None], pause]}]}],
        sliders=[{"active": 0, "steps": slider_steps, "x": 0.14, "len": 0.5, "y": -0.02,
                  "yanchor": "top", "currentvalue": {"prefix": "t = ", "suffix": " s"},
                  "pad": {"t": 0}}],
    )
    return fig
