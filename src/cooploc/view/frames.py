"""Per-step drawing data of a run: truth, estimates with 2-σ ellipses, links, associations.

`frame_data(recording, estimates, rmse)` turns a regenerated recording and the kept
estimates into plain arrays per shown step, which both renderers draw:

- truth: positions of the vehicles and moving features present (the paper's red);
- prior: `Setup.vehicle_prior` at step 0 (blue);
- per estimator: vehicle and feature means with their 2-σ position ellipses
  (x̂ + 2 L [cos φ, sin φ]ᵀ with L Lᵀ the 2 × 2 position covariance), and per vehicle
  the position error ‖p̂ − p‖ (m) and the position NEES eᵀ P⁻¹ e (χ²(2) for a
  consistent estimator). Set-valued estimators (slots, not identities) are scored as
  `metrics.evaluate` scores them: after the optimal assignment to the true vehicles;
- V2V links of the step between the vehicles' true positions, and the V2F detections
  (a line from the measuring vehicle to where the row puts the feature);
- the association each estimator decided: per V2F row a line from the measuring
  vehicle to where the row puts the feature (the vehicle's true position + the
  relative position measured) and on to the true position of the feature it was
  given — straight when right, bent when the row went to another feature — split
  into right and wrong decisions (the truth's origin of the row).

Size limits (the page must stay responsive; every limit that bites is stated in
`FrameData.notes`, which the page shows):

- at most `MAX_FRAMES` frames: above, every s-th step is shown;
- at most `MAX_MARKERS_PER_FRAME` markers (vehicles and features, truth and every
  estimator) in a frame: above, every m-th vehicle and feature by id is shown (the
  same entities in every frame);
- at most `MAX_LINKS_PER_FRAME` V2V links and as many V2F detections per frame
  (every l-th above);
- at most `MAX_POINTS` drawn vertices over all frames (markers, ellipse vertices,
  link and association ends): above, the step stride grows.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from cooploc.gaussian import squared_mahalanobis
from cooploc.metrics import optimal_assignment
from cooploc.types import Estimate, FloatArray, IntArray, Recording, StateSet, lookup_ids

__all__ = [
    "ELLIPSE_VERTICES",
    "MAX_FRAMES",
    "MAX_LINKS_PER_FRAME",
    "MAX_MARKERS_PER_FRAME",
    "MAX_POINTS",
    "FrameData",
    "Layer",
    "ellipses",
    "frame_data",
    "moving_features",
]

MAX_FRAMES = 300
MAX_MARKERS_PER_FRAME = 2000
MAX_LINKS_PER_FRAME = 400
MAX_POINTS = 1_500_000
ELLIPSE_VERTICES = 16
_SIGMAS = 2.0


def ellipses(mean: FloatArray, cov: FloatArray, sigmas: float = _SIGMAS,
             vertices: int = ELLIPSE_VERTICES) -> FloatArray:
    """Closed `sigmas`-σ outlines of 2-D Gaussians, mean (n, 2), cov (n, 2, 2), joined with
    NaN rows: ((vertices + 2) n, 2)."""
    n = len(mean)
    if n == 0:
        return np.zeros((0, 2))
    phi = np.linspace(0.0, 2.0 * np.pi, vertices + 1)
    circle = np.stack([np.cos(phi), np.sin(phi)])                       # (2, V + 1)
    # a tiny jitter keeps Cholesky alive for a degenerate (rank-deficient) covariance
    L = np.linalg.cholesky(cov + 1e-12 * np.eye(2))
    outline = mean[:, :, None] + sigmas * (L @ circle)                  # (n, 2, V + 1)
    outline = np.concatenate([outline, np.full((n, 2, 1), np.nan)], axis=2)
    return outline.transpose(0, 2, 1).reshape(-1, 2)


def _segments(*points: FloatArray) -> FloatArray:
    """Polylines a_i → b_i (→ c_i …), each (n, 2), as one NaN-separated array ((len + 1) n, 2)."""
    if len(points[0]) == 0:
        return np.zeros((0, 2))
    return np.stack([*points, np.full_like(points[0], np.nan)], axis=1).reshape(-1, 2)


@dataclass(frozen=True)
class Layer:
    """One estimator's drawing, one entry per shown frame."""

    ids: list[IntArray] = field(default_factory=list)
    xy: list[FloatArray] = field(default_factory=list)
    ellipses: list[FloatArray] = field(default_factory=list)
    error: list[FloatArray] = field(default_factory=list)
    nees: list[FloatArray] = field(default_factory=list)
    feature_ids: list[IntArray] = field(default_factory=list)
    feature_xy: list[FloatArray] = field(default_factory=list)
    feature_ellipses: list[FloatArray] = field(default_factory=list)
    right: list[FloatArray] = field(default_factory=list)
    wrong: list[FloatArray] = field(default_factory=list)
    has_features: bool = False
    has_association: bool = False


@dataclass(frozen=True)
class FrameData:
    """Everything that changes per frame, over the shown steps.

    `steps` (F,) and `t` (F,) of the shown frames; `truth_*` and `feature_*` the true
    vehicles and moving features per frame; `prior_*` the step-0 prior; `links` (V2V)
    and `detections` (V2F: measuring vehicle → measured point) per frame; `layers` per
    estimator; `rmse[name] = (t, rmse)` of every step (not decimated); `notes` the size
    limits that applied.
    """

    steps: IntArray
    t: FloatArray
    truth_ids: list[IntArray]
    truth_xy: list[FloatArray]
    feature_ids: list[IntArray]
    feature_xy: list[FloatArray]
    prior_xy: FloatArray
    prior_ellipses: FloatArray
    links: list[FloatArray]
    detections: list[FloatArray]
    layers: dict[str, Layer]
    rmse: dict[str, tuple[FloatArray, FloatArray]]
    notes: list[str]


def _position_block(states: StateSet, pos: list[int]) -> tuple[FloatArray, FloatArray]:
    return states.mean[:, pos], states.cov[:, pos][:, :, pos]


def _scored(est_xy: FloatArray, est_cov: FloatArray, est_ids: IntArray, true_ids: IntArray,
            true_xy: FloatArray, set_valued: bool) -> tuple[FloatArray, FloatArray]:
    """Position error (m) and NEES of each estimate; NaN where it has no true counterpart."""
    error = np.full(len(est_ids), np.nan)
    nees = np.full(len(est_ids), np.nan)
    if not len(est_ids) or not len(true_ids):
        return error, nees
    if set_valued:
        rows, cols = optimal_assignment(est_xy, true_xy)
    else:
        col, found = lookup_ids(true_ids, est_ids)
        rows, cols = np.flatnonzero(found), col[found]
    e = true_xy[cols] - est_xy[rows]
    error[rows] = np.hypot(e[:, 0], e[:, 1])
    nees[rows] = squared_mahalanobis(e, est_cov[rows])
    return error, nees


def _subset(ids: IntArray, every: int) -> IntArray:
    """Every `every`-th id in sorted order (the same entities in every frame)."""
    return np.unique(ids)[::every] if every > 1 else np.unique(ids)


def moving_features(recording: Recording) -> np.ndarray:
    """(K,) features that move or come and go (static ones are drawn once, by the scene)."""
    truth = recording.truth
    if truth.feature_ids.size == 0:
        return np.zeros(0, bool)
    still = np.ptp(truth.feature_states[:, :, :2], axis=0).max(axis=1) == 0.0
    return ~(truth.feature_present.all(axis=0) & still)


def _budget(recording: Recording, n_estimators: int, n_feature_layers: int
            ) -> tuple[int, int, tuple[int, int], list[str]]:
    """(step stride, vehicle and feature id stride, V2V and V2F strides) and the notes they need."""
    truth, frames = recording.truth, recording.frames
    T = len(frames)
    n_vehicles = truth.vehicle_present.sum(axis=1)
    moving = moving_features(recording)
    n_features = truth.feature_present[:, moving].sum(axis=1) if moving.size else np.zeros(T)
    n_static = int((~moving).sum()) if moving.size else 0
    markers = n_vehicles * (1 + n_estimators) + n_features * (1 + n_feature_layers) \
        + n_static * n_feature_layers
    notes = []
    every = int(np.ceil(markers.max() / MAX_MARKERS_PER_FRAME)) if T else 1
    if every > 1:
        notes.append(f"up to {int(markers.max())} markers in a frame, more than "
                     f"{MAX_MARKERS_PER_FRAME}: 1 in {every} vehicles and features (by id) is shown")
    n_links = np.array([len(f.links) for f in frames])
    link_every = int(np.ceil(n_links.max() / MAX_LINKS_PER_FRAME)) if T and n_links.max() else 1
    if link_every > 1:
        notes.append(f"up to {int(n_links.max())} V2V links in a step, more than "
                     f"{MAX_LINKS_PER_FRAME}: 1 in {link_every} links is drawn")
    n_v2f = np.array([len(f.batch("v2f", 2)) for f in frames])
    v2f_every = int(np.ceil(n_v2f.max() / MAX_LINKS_PER_FRAME)) if T and n_v2f.max() else 1
    if v2f_every > 1:
        notes.append(f"up to {int(n_v2f.max())} V2F detections in a step, more than "
                     f"{MAX_LINKS_PER_FRAME}: 1 in {v2f_every} is drawn")
    per_entity = 1 + ELLIPSE_VERTICES + 2
    points = (markers / every * per_entity + 3 * n_links / link_every + 3 * n_v2f / v2f_every
              + 8 * n_v2f * n_estimators / every)
    stride = max(int(np.ceil(T / MAX_FRAMES)), int(np.ceil(points.sum() / MAX_POINTS)), 1)
    if stride > 1:
        notes.insert(0, f"{T} steps: 1 in {stride} steps is a frame (at most {MAX_FRAMES} frames "
                        f"and {MAX_POINTS:,} drawn points)")
    return stride, every, (link_every, v2f_every), notes


def frame_data(recording: Recording, estimates: Mapping[str, Sequence[Estimate]],
               rmse: Mapping[str, tuple[FloatArray, FloatArray]] | None = None) -> FrameData:
    """The per-frame drawing data of a run (see the module docstring for what and the limits)."""
    setup, truth, frames = recording.setup, recording.truth, recording.frames
    vpos = list(setup.vehicle_layout.position)
    fpos = list(setup.feature_layout.position) if setup.feature_layout is not None else vpos
    has_features = {n: any(e.features is not None and len(e.features) for e in est)
                    for n, est in estimates.items()}
    stride, every, (link_every, v2f_every), notes = _budget(recording, len(estimates),
                                                            sum(has_features.values()))
    shown_vehicles = _subset(truth.vehicle_ids, every)
    shown_features = _subset(truth.feature_ids, every)
    moving = moving_features(recording)
    steps = np.arange(0, len(frames), stride)

    truth_ids, truth_xy, feature_ids, feature_xy, links, detections = [], [], [], [], [], []
    layers = {n: Layer(has_features=has_features[n],
                       has_association=any("v2f_association" in e.info for e in est))
              for n, est in estimates.items()}
    for k in steps:
        present = truth.vehicle_present[k] & np.isin(truth.vehicle_ids, shown_vehicles)
        ids, xy = truth.vehicle_ids[present], truth.vehicle_states[k, present][:, vpos]
        all_ids = truth.vehicle_ids[truth.vehicle_present[k]]
        all_xy = truth.vehicle_states[k, truth.vehicle_present[k]][:, vpos]
        fon = truth.feature_present[k]
        f_ids, f_xy = truth.feature_ids[fon], truth.feature_states[k, fon][:, fpos]
        truth_ids.append(ids)
        truth_xy.append(xy)
        fshow = np.isin(f_ids, shown_features) & moving[fon]
        feature_ids.append(f_ids[fshow])
        feature_xy.append(f_xy[fshow])
        edges = frames[k].links[::link_every]
        a, _ = lookup_ids(all_ids, edges[:, 0])
        b, _ = lookup_ids(all_ids, edges[:, 1])
        links.append(_segments(all_xy[a], all_xy[b]))
        v2f = frames[k].batch("v2f", 2)
        rows = np.flatnonzero(np.isin(v2f.sensor, shown_vehicles))[::v2f_every]
        at, found = lookup_ids(all_ids, v2f.sensor[rows])
        sensor_xy = all_xy[at[found]]
        detections.append(_segments(sensor_xy, sensor_xy + v2f.z[rows[found]][:, :2]))
        origin = truth.origin[k].get("v2f", np.zeros(0, np.int64))
        for name, est in estimates.items():
            _add_layer(layers[name], est[k], ids, all_ids, all_xy, f_ids, f_xy, shown_vehicles,
                       shown_features, v2f, origin, vpos, fpos)

    prior = setup.vehicle_prior
    prior = prior.take(np.intersect1d(prior.ids, shown_vehicles)) if len(prior) else prior
    prior_xy, prior_cov = _position_block(prior, vpos) if len(prior) else (np.zeros((0, 2)),
                                                                           np.zeros((0, 2, 2)))
    return FrameData(steps, np.array([frames[k].t for k in steps]), truth_ids, truth_xy, feature_ids,
                     feature_xy, prior_xy, ellipses(prior_xy, prior_cov), links, detections, layers,
                     dict(rmse or {}), notes)


def _add_layer(layer: Layer, estimate: Estimate, shown_ids: IntArray, all_ids: IntArray,
               all_xy: FloatArray, f_ids: IntArray, f_xy: FloatArray, shown_vehicles: IntArray,
               shown_features: IntArray, v2f, origin: IntArray, vpos: list[int], fpos: list[int]) -> None:
    set_valued = bool(estimate.info.get("set_valued", False))
    vehicles = estimate.vehicles
    xy, cov = _position_block(vehicles, vpos)
    error, nees = _scored(xy, cov, vehicles.ids, all_ids, all_xy, set_valued)
    keep = np.ones(len(vehicles), bool) if set_valued else np.isin(vehicles.ids, shown_vehicles)
    if set_valued and len(shown_ids) < len(all_ids):  # slots: keep as many as vehicles are shown
        keep[int(np.ceil(len(vehicles) * len(shown_ids) / max(len(all_ids), 1))):] = False
    layer.ids.append(vehicles.ids[keep])
    layer.xy.append(xy[keep])
    layer.ellipses.append(ellipses(xy[keep], cov[keep]))
    layer.error.append(error[keep])
    layer.nees.append(nees[keep])
    features = estimate.features
    if features is not None and len(features):
        fxy, fcov = _position_block(features, fpos)
        fkeep = np.isin(features.ids, shown_features)
        layer.feature_ids.append(features.ids[fkeep])
        layer.feature_xy.append(fxy[fkeep])
        layer.feature_ellipses.append(ellipses(fxy[fkeep], fcov[fkeep]))
    else:
        layer.feature_ids.append(np.zeros(0, np.int64))
        layer.feature_xy.append(np.zeros((0, 2)))
        layer.feature_ellipses.append(np.zeros((0, 2)))
    decided = estimate.info.get("v2f_association")
    right = wrong = np.zeros((0, 2))
    if decided is not None and len(v2f):
        decided = np.asarray(decided, np.int64)[:len(v2f)]
        sensor_at, sensor_ok = lookup_ids(all_ids, v2f.sensor[:len(decided)])
        feature_at, feature_ok = lookup_ids(f_ids, decided)
        rows = (decided >= 0) & sensor_ok & feature_ok & np.isin(v2f.sensor[:len(decided)], shown_vehicles)
        vehicle = all_xy[sensor_at[rows]]
        measured = vehicle + v2f.z[:len(decided)][rows][:, :2]
        end = f_xy[feature_at[rows]]
        ok = decided[rows] == origin[:len(decided)][rows]
        right = _segments(vehicle[ok], measured[ok], end[ok])
        wrong = _segments(vehicle[~ok], measured[~ok], end[~ok])
    layer.right.append(right)
    layer.wrong.append(wrong)
