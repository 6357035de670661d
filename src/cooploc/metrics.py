"""Errors and summary statistics of estimates against the truth (DESIGN §6).

- Position error: Euclidean distance between estimated and true position (m).
- Velocity error: Euclidean distance of the velocity components (m/s), where the
  layout has them.
- Heading error: |wrap(α̂ − α)| in rad, wrapped to [−π, π), where the layout has one;
  where it has none, of the headings an estimator reports in ``Estimate.info["heading"]``
  (`plbp` on `sumo-*`) against `Truth.vehicle_heading`, if the truth keeps it.
- RMSE = sqrt(mean of the squared 2-D position error) over whatever set of steps,
  runs and entities is pooled; `per_entity_rmse` pools steps (and runs) per id.
- `ecdf`: the empirical CDF (sorted values and probabilities i/n).
- `association_accuracy`: share of rows whose decided origin equals the true one.
- Association of V2F rows, two measures (`score_association` computes both over a run,
  from the `Estimate.info` keys that `cooploc.types.Estimate` defines:
  ``v2f_association``, ``v2f_track``, ``v2f_discarded``):

  - *per track over the run* (summary.json ``association_accuracy``): estimators that
    start their own feature tracks (ids of their own) are scored by giving each track
    the true feature most of its rows came from over the whole run
    (`track_identities`; `relabel` renames the feature estimates the same way), and
    the measure is the share of paired rows whose origin is their track's feature. A
    track whose rows switch between two features for part of the run still counts
    those rows as right if they are the majority, so this measures how consistently
    rows are grouped, not whether each was paired with the right feature belief.
  - *per step* (``association_accuracy_per_step``), the measure of Brambilla et al.
    2020 §V ("probability of correct measurement-feature association", 54 % / 92 % for
    ICP-DA-LC at d_f = 0.5 / 3 m; Figs. 9 and 11): the share of paired rows (rows
    left unused are not in it, so that discarding ambiguous rows can raise it, as the
    paper's Fig. 9 says it does) that were paired with the belief of their true
    feature. The paper's estimators hold one belief per true feature, so the pairing
    α̂_ik = ℓ is right when row ℓ came from feature k. Estimators that name tracks
    themselves are matched to the true features at every step (`paired_features`):
    the tracks estimated at step k and the true features present at k are paired
    one-to-one by the optimal assignment of their positions (`optimal_assignment`,
    minimum summed squared distance: a shift common to all tracks does not change it
    when there are as many tracks as features; a track left over stands for no
    feature); a row given to a track at step k is right when its origin is the
    feature that track was matched to at the last step before k at which it was
    estimated — the belief the association of step k paired it with (the prior
    b_k^(0) of eqs. 12–13) — or, for a track first estimated at k, at k. A swap of
    two tracks' features therefore costs the rows of the step where it happens, as a
    wrong pairing costs the paper's measure, whatever the rest of the run does.
    Estimators that decide by the scenario's feature ids (``v2f_association``) have
    the identities fixed, and both measures are the same share.
- `nees`: normalised estimation error squared (x − x̂)ᵀ P⁻¹ (x − x̂), for consistency
  checks against χ² bounds. `evaluate` reports the 2-D *position* NEES of every scored
  entity (the position block of the estimate's covariance; χ²₂ for a consistent
  estimator), and `nees_band` gives the χ² 95 % band of its mean over many samples.

Only entities that are both estimated and present in the truth at a step are scored;
features are matched by id.

Set-valued estimates (Zhang 2016: `sme-pf`, `sme-ukf`, `gm-phd`) mark themselves with
``Estimate.info["set_valued"] = True``: their vehicle ids are slots, not identities.
`evaluate` then relabels them per step by the optimal assignment of estimated to true
positions (`optimal_assignment`, minimum summed squared distance,
`scipy.optimize.linear_sum_assignment`) before scoring — the paper's "state-to-target
association process" (Zhang §4.1). `ospa` scores the sets without labels (Schuhmacher,
Vo & Vo 2008; cut-off c = `OSPA_CUTOFF` m, order p = `OSPA_ORDER`), and
`total_rmse` is Zhang's eq. (20): sqrt(mean over steps of the *sum* over vehicles of
the squared position error); `total_rmse_per_run_and_step` gives the same error of the
whole system per run and per step (Gulati et al. 2017 eq. 21, Table I and Figs. 4/6).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from cooploc.errors import InvalidInputError
from cooploc.gaussian import squared_mahalanobis
from cooploc.geometry import wrap_angle
from cooploc.types import (
    Estimate,
    FloatArray,
    IntArray,
    Recording,
    StateLayout,
    StateSet,
    Truth,
    lookup_ids,
)

__all__ = [
    "FEATURE",
    "OSPA_CUTOFF",
    "OSPA_ORDER",
    "VEHICLE",
    "AssociationScore",
    "ErrorTable",
    "association_accuracy",
    "ecdf",
    "evaluate",
    "nees",
    "nees_band",
    "optimal_assignment",
    "ospa",
    "ospa_per_step",
    "paired_features",
    "per_entity_rmse",
    "relabel",
    "rmse",
    "score_association",
    "set_errors",
    "total_rmse",
    "total_rmse_per_run_and_step",
    "track_identities",
]

VEHICLE, FEATURE = 0, 1
OSPA_CUTOFF = 10.0  # m: a vehicle missed or placed 10 m off costs the same
OSPA_ORDER = 2.0
KIND_NAMES = {VEHICLE: "vehicle", FEATURE: "feature"}


def rmse(errors: npt.ArrayLike) -> float:
    """sqrt(mean(e²)) of the entries that are not NaN; NaN for none.

    NaN means "no such error" (a component the layout lacks, a point left unestimated)
    and is skipped; an infinite error (a diverged estimate) is not: the RMSE is then
    infinite, never the RMSE of the others.
    """
    e = np.asarray(errors, dtype=float)
    e = e[~np.isnan(e)]
    with np.errstate(over="ignore"):  # a diverged error squares to inf: that is the answer
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def per_entity_rmse(ids: IntArray, errors: FloatArray) -> dict[int, float]:
    """RMSE per entity id (pooled over everything else in the arrays)."""
    ids = np.asarray(ids)
    errors = np.asarray(errors, dtype=float)
    unique, inverse = np.unique(ids, return_inverse=True)
    sq = np.bincount(inverse, weights=errors**2, minlength=unique.size)
    count = np.bincount(inverse, minlength=unique.size)
    return {int(i): float(np.sqrt(s / c)) for i, s, c in zip(unique, sq, count, strict=True)}


def ecdf(values: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Empirical CDF: sorted values x and P(X ≤ x_i) = i/n."""
    x = np.sort(np.asarray(values, dtype=float).ravel())
    return x, np.arange(1, x.size + 1) / max(x.size, 1)


def association_accuracy(decided: IntArray, true_origin: IntArray) -> float:
    """Correct decisions / all decisions (decided origin ids against the true ones)."""
    decided, true_origin = np.asarray(decided), np.asarray(true_origin)
    return float(np.mean(decided == true_origin)) if decided.size else float("nan")


def track_identities(tracks: Sequence[IntArray], origins: Sequence[IntArray]) -> dict[int, int]:
    """The true feature each estimated track stands for: the most frequent true origin of
    the rows the estimator assigned to it over the whole run (ties: the smaller id).

    `tracks[k]` (M_k,) is the track id an estimator gave each V2F row of step k (−1:
    none); `origins[k]` the rows' true origins (−1: clutter). Estimators that name
    their own features (new tracks, not the scenario's ids) are scored through this.
    """
    track = np.concatenate([np.asarray(t, np.int64) for t in tracks]) if tracks else np.zeros(0, np.int64)
    origin = np.concatenate([np.asarray(o, np.int64) for o in origins]) if origins else np.zeros(0, np.int64)
    used = track >= 0
    pairs, counts = np.unique(np.stack([track[used], origin[used]], axis=1), axis=0, return_counts=True)
    order = np.lexsort((pairs[:, 1], -counts, pairs[:, 0]))     # per track: most rows, then smaller id
    pairs = pairs[order]
    first = np.ones(len(pairs), dtype=bool)
    first[1:] = pairs[1:, 0] != pairs[:-1, 0]
    return {int(t): int(o) for t, o in pairs[first]}


def relabel(states: StateSet, identity: Mapping[int, int]) -> StateSet:
    """Estimated entities renamed by `identity` (track → true id); unmapped or clutter
    tracks are dropped, and of several tracks for one true id the first is kept."""
    new = np.array([identity.get(int(i), -1) for i in states.ids], dtype=np.int64)
    keep = new >= 0
    _, first = np.unique(new[keep], return_index=True)
    rows = np.flatnonzero(keep)[np.sort(first)]
    return StateSet(new[rows], states.mean[rows], states.cov[rows])


def paired_features(row_tracks: Sequence[IntArray], track_ids: Sequence[IntArray],
                    track_positions: Sequence[FloatArray], feature_ids: Sequence[IntArray],
                    feature_positions: Sequence[FloatArray]) -> list[IntArray]:
    """The true feature whose belief each V2F row was paired with, step by step (−1: the
    row was not paired, or its track stands for no feature), for the per-step
    association measure (module docstring).

    Step k's arrays: `row_tracks[k]` (M_k,) the track id each row was given (−1: none);
    the tracks estimated at k, `track_ids[k]` (n_k,) at `track_positions[k]` (n_k, 2) m;
    the true features present at k, `feature_ids[k]` (m_k,) at `feature_positions[k]`
    (m_k, 2) m. At every step the tracks and the features are matched one-to-one by
    `optimal_assignment`. A row given to a track at step k was paired with the feature
    that track was matched to at the last step before k at which it was estimated; if
    the track was first estimated at k, with its match at k.
    """
    out: list[IntArray] = []
    last: dict[int, int] = {}        # track → its match at the last step it was estimated
    for rows, ids, pos, fids, fpos in zip(row_tracks, track_ids, track_positions, feature_ids,
                                          feature_positions, strict=True):
        now = _matched(ids, pos, fids, fpos)
        out.append(np.array([last.get(t, now.get(t, -1)) if t >= 0 else -1
                             for t in np.asarray(rows, np.int64).tolist()], dtype=np.int64))
        last.update(now)
    return out


def _matched(ids: IntArray, positions: FloatArray, feature_ids: IntArray, feature_positions: FloatArray
             ) -> dict[int, int]:
    """Track id → the true feature id the optimal assignment gives it (−1: left over)."""
    ids, feature_ids = np.asarray(ids, np.int64), np.asarray(feature_ids, np.int64)
    now = dict.fromkeys(ids.tolist(), -1)
    if ids.size and feature_ids.size:
        rows, cols = optimal_assignment(np.asarray(positions, float), np.asarray(feature_positions, float))
        now.update(zip(ids[rows].tolist(), feature_ids[cols].tolist(), strict=True))
    return now


@dataclass(frozen=True)
class AssociationScore:
    """V2F association of one run: `correct` of `total` paired rows went to their true
    origin by the track measure, `per_step_correct` of them by the per-step measure
    (module docstring; the same count for estimators that decide by feature id);
    `discarded` of `rows` were left unused (None for estimators that name no tracks)."""

    correct: int
    total: int
    discarded: int | None = None
    rows: int | None = None
    per_step_correct: int = 0


def score_association(recording: Recording, estimates: Sequence[Estimate]
                      ) -> tuple[list[Estimate], AssociationScore | None]:
    """Association of a run by both measures (module docstring), and the estimates with
    self-named feature tracks renamed to the true feature they stand for over the run
    (`track_identities`, `relabel`).

    Rows decided by feature id (``info["v2f_association"]``) count as correct when the
    id is their true origin; rows given to an estimator's own track
    (``info["v2f_track"]``) when the track stands for their true origin — over the run
    (`correct`), or at the row's step (`per_step_correct`, `paired_features`). None
    when no estimate reports either key.
    """
    correct = total = dropped = rows = per_step = 0
    steps, tracks, track_origins = [], [], []
    for k, estimate in enumerate(estimates):
        true = recording.truth.origin[k].get("v2f", np.zeros(0, np.int64))
        decided = estimate.info.get("v2f_association")
        if decided is not None and "v2f_track" not in estimate.info:
            hits = int(np.sum(np.asarray(decided) == true))
            correct, per_step, total = correct + hits, per_step + hits, total + int(true.size)
        track = estimate.info.get("v2f_track")
        if track is not None:
            steps.append(k)
            tracks.append(np.asarray(track))
            track_origins.append(true)
            dropped += int(estimate.info.get("v2f_discarded", 0))
            rows += int(true.size)
    if not tracks:
        return list(estimates), (AssociationScore(correct, total, per_step_correct=per_step)
                                 if total else None)
    identity = track_identities(tracks, track_origins)
    paired_with = _paired_features_of_run(recording, estimates, steps, tracks)
    for track, true, feature in zip(tracks, track_origins, paired_with, strict=True):
        paired = track >= 0
        named = np.array([identity.get(int(t), -2) for t in track[paired]], dtype=np.int64)
        correct += int(np.sum(named == true[paired]))
        per_step += int(np.sum(feature[paired] == true[paired]))
        total += int(paired.sum())
    renamed = [dataclasses.replace(e, features=relabel(e.features, identity))
               if e.features is not None else e for e in estimates]
    return renamed, AssociationScore(correct, total, dropped, rows, per_step)


def _paired_features_of_run(recording: Recording, estimates: Sequence[Estimate], steps: Sequence[int],
                            tracks: Sequence[IntArray]) -> list[IntArray]:
    """`paired_features` of the rows `tracks` of `steps` (the steps that report tracks)."""
    truth, layout = recording.truth, recording.setup.feature_layout
    if layout is None or truth.feature_ids.size == 0:
        return [np.full(t.size, -1, np.int64) for t in tracks]
    pos = list(layout.position)
    track_ids, track_pos, feature_ids, feature_pos = [], [], [], []
    for k in steps:
        est = estimates[k].features
        track_ids.append(np.zeros(0, np.int64) if est is None else est.ids)
        track_pos.append(np.zeros((0, len(pos))) if est is None else est.mean[:, pos])
        present = truth.feature_present[k]
        feature_ids.append(truth.feature_ids[present])
        feature_pos.append(truth.feature_states[k][present][:, pos])
    return paired_features(tracks, track_ids, track_pos, feature_ids, feature_pos)


def nees(estimate: StateSet, true_states: FloatArray) -> FloatArray:
    """(x − x̂)ᵀ P⁻¹ (x − x̂) per entity; χ²(dx) distributed for a consistent filter."""
    return squared_mahalanobis(true_states - estimate.mean, estimate.cov)


def nees_band(samples: int, dim: int = 2, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided `probability` band of the mean of `samples` independent χ²(dim) values.

    The sum of N χ²(d) values is χ²(N d), so the mean lies in
    [χ²_{Nd}((1 − p)/2), χ²_{Nd}((1 + p)/2)] / N. Errors of one run are correlated over
    steps, so for a time average over K steps of M runs this band (N = M K) is the
    usual, optimistic consistency test (Bar-Shalom, Li & Kirubarajan 2001, §5.4).
    With `dim` = 1 and N = Σ dof it is the band of ΣNIS / Σdof (summary.json's `nis_mean`):
    a consistent filter's innovations are white, so ΣNIS ~ χ²(Σ dof).
    """
    from scipy.stats import chi2

    tail = (1.0 - probability) / 2
    low, high = chi2.ppf([tail, 1.0 - tail], samples * dim)
    return float(low / samples), float(high / samples)


def _position_nees(est: StateSet, rows: npt.NDArray[np.bool_], true: FloatArray,
                   layout: StateLayout) -> FloatArray:
    """2-D position NEES of the estimates `rows` against their true states (n,)."""
    pos = list(layout.position)
    return squared_mahalanobis(true[:, pos] - est.mean[rows][:, pos], est.cov[rows][:, pos][:, :, pos])


@dataclass(frozen=True)
class ErrorTable:
    """Errors in long format, one row per (step, entity); columns are arrays.

    `err_vel` and `err_heading` are NaN where the layout has no such component; `nees`
    is the 2-D position NEES (χ²₂ for a consistent estimator).
    """

    step: IntArray
    t: FloatArray
    kind: IntArray
    id: IntArray
    err_pos: FloatArray
    err_vel: FloatArray
    err_heading: FloatArray
    nees: FloatArray

    def __len__(self) -> int:
        return self.step.size

    def select(self, rows: npt.ArrayLike) -> ErrorTable:
        return ErrorTable(*(getattr(self, f)[rows] for f in self.__dataclass_fields__))

    @classmethod
    def concatenate(cls, tables: Sequence[ErrorTable]) -> ErrorTable:
        if not tables:
            empty = np.zeros(0)
            return cls(empty.astype(int), empty, empty.astype(int), empty.astype(int),
                       empty, empty, empty, empty)
        return cls(*(np.concatenate([getattr(t, f) for t in tables])
                     for f in cls.__dataclass_fields__))


def _entity_errors(mean: FloatArray, true: FloatArray, layout: StateLayout
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
    pos = list(layout.position)
    err_pos = np.linalg.norm(mean[:, pos] - true[:, pos], axis=1)
    err_vel = np.full(err_pos.shape, np.nan)
    if layout.velocity is not None:
        vel = list(layout.velocity)
        err_vel = np.linalg.norm(mean[:, vel] - true[:, vel], axis=1)
    err_heading = np.full(err_pos.shape, np.nan)
    if layout.heading is not None:
        err_heading = np.abs(wrap_angle(mean[:, layout.heading] - true[:, layout.heading]))
    return err_pos, err_vel, err_heading


def _info_heading_errors(estimate: Estimate, ok: npt.NDArray[np.bool_], truth: Truth, k: int,
                         col: IntArray, default: FloatArray) -> FloatArray:
    """Heading errors of an estimator that reports its vehicles' headings beside a layout
    without one (`info["heading"]` (n,), in the order of `estimate.vehicles`, e.g. `plbp`
    on `sumo-*`), against `Truth.vehicle_heading`; `default` where either is missing."""
    heading = estimate.info.get("heading")
    if heading is None or truth.vehicle_heading is None or estimate.info.get("set_valued"):
        return default
    heading = np.asarray(heading, dtype=float)
    if heading.shape != (len(estimate.vehicles),):
        raise InvalidInputError(f"Estimate.info['heading'] must have shape ({len(estimate.vehicles)},), "
                                f"got {heading.shape}")
    return np.abs(wrap_angle(heading[ok] - truth.vehicle_heading[k, col]))


def _relabel_by_assignment(est: StateSet, ids: IntArray, states: FloatArray,
                           layout: StateLayout) -> StateSet:
    """The estimates that the optimal assignment pairs with true vehicles, relabelled with
    those vehicles' ids (unpaired estimates are dropped)."""
    pos = list(layout.position)
    rows, cols = optimal_assignment(est.mean[:, pos], states[:, pos])
    return StateSet(ids[cols], est.mean[rows], est.cov[rows])


def ospa_per_step(recording: Recording, estimates: Sequence[Estimate], cutoff: float = OSPA_CUTOFF,
                  order: float = OSPA_ORDER) -> FloatArray:
    """OSPA (m) between estimated and present true vehicle positions at every step (T,)."""
    truth, pos = recording.truth, list(recording.setup.vehicle_layout.position)
    return np.array([
        ospa(e.vehicles.mean[:, pos], truth.vehicle_states[k][truth.vehicle_present[k]][:, pos],
             cutoff, order)
        for k, e in enumerate(estimates)
    ])


def total_rmse(step: IntArray, err_pos: FloatArray, run: IntArray | None = None) -> float:
    """Zhang 2016 eq. (20): sqrt(mean over (run, step) of Σ_vehicles err²); NaN for no rows."""
    step = np.asarray(step)
    run = np.zeros_like(step) if run is None else np.asarray(run)
    if step.size == 0:
        return float("nan")
    _, group = np.unique(np.stack([run, step]), axis=1, return_inverse=True)
    sums = np.bincount(group.ravel(), weights=np.asarray(err_pos, dtype=float) ** 2)
    return float(np.sqrt(sums.mean()))


def total_rmse_per_run_and_step(run: IntArray, step: IntArray, err_pos: FloatArray
                                ) -> tuple[FloatArray, FloatArray]:
    """Eq. (20) per run (R,) and per step (T,): the error of the whole system.

    With S[r, k] = Σ_vehicles err² of run r (0 … R − 1) at step k (0 … T − 1), zero where
    no row was scored: per run sqrt(mean_k S[r, k]), per step sqrt(mean_r S[r, k]).
    """
    run, step = np.asarray(run, dtype=np.int64), np.asarray(step, dtype=np.int64)
    shape = (int(run.max()) + 1, int(step.max()) + 1) if step.size else (0, 0)
    sums = np.zeros(shape)
    np.add.at(sums, (run, step), np.asarray(err_pos, dtype=float) ** 2)  # Σ over vehicles
    return np.sqrt(sums.mean(axis=1)), np.sqrt(sums.mean(axis=0))


def evaluate(recording: Recording, estimates: Sequence[Estimate]) -> ErrorTable:
    """Errors of every estimated vehicle and feature at every step of the recording."""
    truth, setup = recording.truth, recording.setup
    if len(estimates) > len(recording.frames):
        raise InvalidInputError(f"evaluate: {len(estimates)} estimates for a recording of "
                                f"{len(recording.frames)} frames")
    columns: list[tuple] = []
    for k, estimate in enumerate(estimates):
        t = recording.time_of(k)
        parts = [(VEHICLE, estimate.vehicles, truth.vehicle_ids, truth.vehicle_states[k],
                  truth.vehicle_present[k], setup.vehicle_layout)]
        if estimate.features is not None and setup.feature_layout is not None:
            parts.append((FEATURE, estimate.features, truth.feature_ids, truth.feature_states[k],
                          truth.feature_present[k], setup.feature_layout))
        for kind, est, ids, states, present, layout in parts:
            if len(est) == 0:
                continue
            if kind == VEHICLE and estimate.info.get("set_valued"):
                est = _relabel_by_assignment(est, ids[present], states[present], layout)
                if len(est) == 0:
                    continue
            col, ok = lookup_ids(ids, est.ids)
            ok[ok] = present[col[ok]]  # scored: estimated, known to the truth and present
            if not ok.any():
                continue
            e_pos, e_vel, e_head = _entity_errors(est.mean[ok], states[col[ok]], layout)
            if kind == VEHICLE and layout.heading is None:
                e_head = _info_heading_errors(estimate, ok, truth, k, col[ok], e_head)
            n = e_pos.size
            columns.append((np.full(n, k), np.full(n, t), np.full(n, kind), est.ids[ok],
                            e_pos, e_vel, e_head, _position_nees(est, ok, states[col[ok]], layout)))
    if not columns:
        return ErrorTable.concatenate([])
    return ErrorTable(*(np.concatenate(c) for c in zip(*columns, strict=True)))


# ----------------------------------------------------------------------------
# set-valued estimates (Zhang 2016: SME and PHD estimates carry no identities)
# ----------------------------------------------------------------------------


def optimal_assignment(estimated: FloatArray, true: FloatArray) -> tuple[IntArray, IntArray]:
    """Rows (into `estimated`) and columns (into `true`) of the assignment that minimises the
    summed squared distance (`scipy.optimize.linear_sum_assignment`); (n, d), (m, d) points."""
    from scipy.optimize import linear_sum_assignment

    estimated, true = np.atleast_2d(estimated), np.atleast_2d(true)
    if estimated.shape[0] == 0 or true.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    cost = ((estimated[:, None, :] - true[None, :, :]) ** 2).sum(-1)
    rows, cols = linear_sum_assignment(cost)
    return rows.astype(np.int64), cols.astype(np.int64)


def set_errors(estimated: FloatArray, true: FloatArray) -> FloatArray:
    """Euclidean error of each true point (m,) after the optimal assignment; NaN where no
    estimate is left for it (fewer estimates than true points)."""
    rows, cols = optimal_assignment(estimated, true)
    out = np.full(np.atleast_2d(true).shape[0], np.nan)
    out[cols] = np.linalg.norm(np.atleast_2d(estimated)[rows] - np.atleast_2d(true)[cols], axis=1)
    return out


def ospa(estimated: FloatArray, true: FloatArray, cutoff: float = 10.0, order: float = 2.0) -> float:
    """OSPA distance (Schuhmacher, Vo & Vo 2008) between point sets (n, d) and (m, d), in m.

    d_c(x, y) = min(c, ‖x − y‖); for n ≤ m,
    OSPA = ( (min_π Σ_i d_c(x_i, y_π(i))^p + c^p (m − n)) / m )^{1/p}; 0 for two empty sets.
    """
    from scipy.optimize import linear_sum_assignment

    X, Y = np.atleast_2d(estimated), np.atleast_2d(true)
    n, m = X.shape[0], Y.shape[0]
    if n == 0 and m == 0:
        return 0.0
    if n == 0 or m == 0:
        return float(cutoff)
    dist = np.minimum(np.linalg.norm(X[:, None, :] - Y[None, :, :], axis=-1), cutoff) ** order
    rows, cols = linear_sum_assignment(dist)
    total = dist[rows, cols].sum() + cutoff**order * abs(m - n)
    return float((total / max(n, m)) ** (1.0 / order))
