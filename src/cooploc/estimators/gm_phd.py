r"""`gm-phd`: Gaussian-mixture PHD filter (Vo & Ma 2006) on the anonymous GPS rows — Zhang 2016's baseline.

Paper: B.-N. Vo and W.-K. Ma, "The Gaussian mixture probability hypothesis density
filter", IEEE Trans. Signal Processing 54(11), 2006 (Tables I–III); used by Zhang et al.
2016 §4.1 on the internal (GPS) measurements only — the radar's frame is unknown.

The PHD of the vehicles is a Gaussian mixture Σ_j w_j N(x; m_j, P_j): prediction with
survival p_S and a measurement-driven birth intensity (Table I, eqs. 20–21), the update
with detection probability p_D and clutter intensity κ = λ / V (eqs. 22–27) over every
component × row pair at once in the log domain, pruning and merging (Table II), and
extraction of exactly one state per connected vehicle (each where the most PHD mass is
still unexplained, `extract_count`; Table III's own count is kept in `info`). Estimates
are set-valued (``info["set_valued"]``).

In traffic (`sumo-*`, issue 19): a vehicle that connects is born on the row an optimal
assignment to the predicted components leaves unexplained (as a posterior component; its
row is left out of the update); one that leaves fades with p_S and the missed-detection
weight 1 − p_D and is pruned. Where the GNSS rows name their vehicle (`use_identities`),
each vehicle has its own PHD: components carry its id as a label, a row updates only its
vehicle's components, merging never joins two labels, and each vehicle's estimate is its
heaviest component (not set-valued). Anonymous rows (Zhang's) leave every label at −1:
the plain GM-PHD, unchanged. Odometry (identified by construction) is fused into its
vehicle's components by stochastic cloning before the GNSS update, as `gnss-kf` does
(`gaussian.kf_update_relative`), their weights renormalised within the label by the row's
likelihood; with anonymous rows (no labels) it is left aside.

The update written out, the extraction rule, births, labels, and the choices the paper
leaves open (p_D cap, p_S, κ = 0 without clutter): docs/gm_phd.md. Stone Soup's GM-PHD is
the reference of tests/test_gm_phd.py.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from cooploc.association import unexplained_rows
from cooploc.errors import EstimatorError
from cooploc.estimators.base import checked_states, default_birth_cov, predict_steps
from cooploc.gaussian import Gaussians, kf_update_relative, symmetrize
from cooploc.params import Params, param
from cooploc.particles import log_sum_exp
from cooploc.registry import register_estimator
from cooploc.types import Estimate, FloatArray, Frame, IntArray, Setup, StateSet

__all__ = ["GMPHD", "GMPHDParams", "Mixture", "extract_count", "merge_components", "phd_update"]


@dataclass(frozen=True, slots=True)
class Mixture:
    """A Gaussian mixture intensity: log_w (J,), mean (J, dx), cov (J, dx, dx), and
    label (J,) the vehicle id a component is of, −1 where unknown (None: all −1)."""

    log_w: FloatArray
    mean: FloatArray
    cov: FloatArray
    label: IntArray | None = None

    def __len__(self) -> int:
        return self.log_w.size

    @property
    def labels(self) -> IntArray:
        return np.full(self.log_w.size, -1, dtype=np.int64) if self.label is None else self.label

    @classmethod
    def empty(cls, dx: int) -> Mixture:
        return cls(np.zeros(0), np.zeros((0, dx)), np.zeros((0, dx, dx)))

    def take(self, rows: Any) -> Mixture:
        return Mixture(self.log_w[rows], self.mean[rows], self.cov[rows],
                       None if self.label is None else self.label[rows])

    @staticmethod
    def concatenate(parts: list[Mixture]) -> Mixture:
        labelled = any(p.label is not None for p in parts)
        return Mixture(np.concatenate([p.log_w for p in parts]),
                       np.concatenate([p.mean for p in parts]),
                       np.concatenate([p.cov for p in parts]),
                       np.concatenate([p.labels for p in parts]) if labelled else None)


def phd_update(prior: Mixture, z: FloatArray, R: FloatArray, H: FloatArray,
               detection_probability: float, clutter_intensity: float,
               subject: IntArray | None = None) -> Mixture:
    """The GM-PHD update (Vo & Ma Table I, steps 3–4) for rows z (M, dz), R (M, dz, dz).

    Returns the (1 + M) J components: the missed-detection copies first, then for each
    row the J updated components. With `subject` (M,) (−1: anonymous), a row that names
    a vehicle updates only the components of that label or of none (label −1), and the
    updated components take its label: each labelled vehicle has its own PHD.
    """
    J, dx = prior.mean.shape
    M = z.shape[0]
    log_pd = np.log(detection_probability)
    missed = Mixture(prior.log_w + np.log1p(-detection_probability), prior.mean, prior.cov, prior.label)
    if M == 0 or J == 0:
        return missed
    PHt = prior.cov @ H.T                                               # (J, dx, dz)
    S = symmetrize((H @ PHt)[:, None] + R[None])                         # (J, M, dz, dz)
    L = np.linalg.cholesky(S)
    innovation = z[None] - (prior.mean @ H.T)[:, None]                   # (J, M, dz)
    white = np.linalg.solve(L, innovation[..., None])[..., 0]
    log_q = (-0.5 * (white**2).sum(-1) - np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(-1)
             - 0.5 * z.shape[1] * np.log(2 * np.pi))                     # log q_j(z) (J, M)
    # K = P Hᵀ S⁻¹ for every pair: solve S Kᵀ = H P
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)[:, None]), -1, -2)  # (J, M, dx, dz)
    mean = prior.mean[:, None] + np.einsum("jmab,jmb->jma", K, innovation)
    I_KH = np.eye(dx) - K @ H                                             # (J, M, dx, dx)
    # Joseph form: (I − K H) P (I − K H)ᵀ + K R Kᵀ
    cov = symmetrize(I_KH @ prior.cov[:, None] @ np.swapaxes(I_KH, -1, -2)
                     + K @ R[None] @ np.swapaxes(K, -1, -2))
    numerator = log_pd + prior.log_w[:, None] + log_q                    # log p_D w_j q_j(z)
    label = None
    if subject is not None:
        other = (subject[None] >= 0) & (prior.labels[:, None] >= 0) & (prior.labels[:, None] != subject[None])
        numerator = np.where(other, -np.inf, numerator)                  # another vehicle's PHD
        label = np.where(subject[:, None] >= 0, subject[:, None], prior.labels[None]).reshape(-1)
    total = log_sum_exp(numerator, axis=0)                                  # log Σ_l p_D w_l q_l(z)
    log_kappa = np.log(clutter_intensity) if clutter_intensity > 0 else -np.inf
    with np.errstate(invalid="ignore"):   # a row no component may explain adds nothing
        log_w = np.nan_to_num(numerator - np.logaddexp(log_kappa, total)[None], nan=-np.inf)  # eq. (26)
    detected = Mixture(log_w.T.reshape(-1), np.swapaxes(mean, 0, 1).reshape(-1, dx),
                       np.swapaxes(cov, 0, 1).reshape(-1, dx, dx), label)
    return Mixture.concatenate([missed, detected])


def extract_count(mixture: Mixture, n: int, position: IntArray, gate: float) -> IntArray:
    """Indices of `n` components (with repeats) to report as the `n` vehicles' estimates.

    Each pick goes where the most PHD mass is still unexplained. Two components are near
    each other when their positions are within the merging threshold `gate` (squared
    Mahalanobis distance of p_j − p_i under P_i + P_j, so that "near" is symmetric); the
    mass near a component is the summed weight of the components near it, and a pick
    explains one unit of the mass near every component near it. The pick is, among the
    components near the one with the most unexplained mass, the one with the most weight
    of its own not yet picked (each pick takes one unit); ties (within 10⁻⁹) go to the
    heavier. The picks come back sorted: the slots of a set-valued estimate carry no order.

    So a component of weight 2 (two vehicles merged) is picked twice, and where two pairs
    of vehicles cross at once — each pair two components, of weights 1.48 and 0.54 beside
    1.47 and 0.47 — each pair gets two picks. Ranking the components by their own
    remaining weight alone (a pick lowers its component's weight by one) picks the 1.48
    a second time before the 0.47 and leaves the other pair one estimate short.
    O(n J + J² d³) for J components.
    """
    w = np.exp(mixture.log_w)
    pos = mixture.mean[:, position]                                        # (J, d)
    P = mixture.cov[:, position[:, None], position[None, :]]              # (J, d, d)
    diff = pos[None, :, :] - pos[:, None, :]                              # (i, j): p_j − p_i
    S = P[:, None] + P[None, :]                                            # cov of p_j − p_i
    d2 = np.einsum("ijd,ijd->ij", diff, np.linalg.solve(S, diff[..., None])[..., 0])
    near = d2 <= gate                                                      # symmetric
    mass = near @ w
    explained = np.zeros(w.size)
    own = w.copy()                                                         # weight not yet picked
    picks = np.empty(n, dtype=np.int64)
    order = np.argsort(-w, kind="stable")                                 # ties: heavier first
    rank = np.empty(w.size, dtype=np.int64)
    rank[order] = np.arange(w.size)
    for t in range(n):  # n picks of O(J) each
        where = _first_best(mass - explained, rank)
        there = np.flatnonzero(near[where])
        picks[t] = there[_first_best(own[there], rank[there])]
        own[picks[t]] -= 1.0
        explained += near[:, picks[t]]
    return np.sort(picks)   # set-valued: slots in component order, whatever the pick order


def _first_best(score: FloatArray, rank: IntArray) -> int:
    """Index of the best `score`, counting scores within 10⁻⁹ of it as ties, which go to
    the lowest `rank`: round-off (a translated origin) must not decide between equals."""
    tied = np.flatnonzero(score >= score.max() - 1e-9)
    return int(tied[np.argmin(rank[tied])])


def merge_components(mixture: Mixture, prune_threshold: float, merge_threshold: float,
                     max_components: int) -> Mixture:
    """Pruning, merging and capping (Vo & Ma Table II), vectorised over components.

    The cap J_max = `max_components` holds for the whole mixture, or per label where the
    components are labelled (each vehicle's PHD its own).
    """
    keep = mixture.log_w > np.log(prune_threshold)
    m = mixture.take(keep)
    if len(m) == 0:
        return m
    remaining = np.ones(len(m), dtype=bool)
    precision_L = np.linalg.cholesky(m.cov)                               # P_i = L Lᵀ
    out_w, out_m, out_P, out_l = [], [], [], []
    while remaining.any():
        idx = np.flatnonzero(remaining)
        j = idx[np.argmax(m.log_w[idx])]                                  # heaviest component
        d = m.mean[idx] - m.mean[j]
        white = np.linalg.solve(precision_L[idx], d[..., None])[..., 0]
        # (m_i − m_j)ᵀ P_i⁻¹ (…) ≤ U, never across two vehicles' labels
        group = idx[((white**2).sum(-1) <= merge_threshold) & (m.labels[idx] == m.labels[j])]
        log_w = log_sum_exp(m.log_w[group], axis=None)
        w = np.exp(m.log_w[group] - log_w)                                # normalised within the group
        mean = w @ m.mean[group]
        spread = m.mean[group] - mean
        cov = np.einsum("g,gij->ij", w, m.cov[group]) + np.einsum("g,gi,gj->ij", w, spread, spread)
        out_w.append(log_w)
        out_m.append(mean)
        out_P.append(symmetrize(cov))
        out_l.append(m.labels[j])
        remaining[group] = False
    merged = Mixture(np.array(out_w), np.array(out_m), np.array(out_P),
                     None if m.label is None else np.array(out_l, dtype=np.int64))
    if merged.label is None:
        if len(merged) > max_components:
            merged = merged.take(np.argsort(-merged.log_w, kind="stable")[:max_components])
        return merged
    # labelled: each vehicle's PHD is capped on its own, so that a city with more vehicles
    # than J_max does not lose whole vehicles to the cap
    order = np.lexsort((-merged.log_w, merged.label))                    # by label, heaviest first
    labels = merged.label[order]
    starts = np.r_[0, np.flatnonzero(np.diff(labels)) + 1]
    rank = np.arange(labels.size) - np.repeat(starts, np.diff(np.r_[starts, labels.size]))
    if rank.max() < max_components:
        return merged
    return merged.take(np.sort(order[rank < max_components]))


@dataclass(frozen=True)
class GMPHDParams(Params):
    """`gm-phd` parameters (defaults: Vo & Ma 2006 §VI where they give one).

    survival_probability : p_S.
    max_detection_probability : cap on the setup's P_D (module docstring).
    birth_weight : weight of each measurement-driven birth component (0: no births).
    prune_threshold : T of Table II.
    merge_threshold : U of Table II (squared Mahalanobis distance).
    max_components : J_max of Table II: of the whole mixture with anonymous rows, of each
        vehicle's PHD with identified rows (a city has more vehicles than Vo & Ma's 100).
    use_identities : where the GNSS rows name their vehicle (`GnssPosition`), each vehicle
        has its own PHD (components labelled with its id; docs/gm_phd.md); False: the
        identities are ignored, as with anonymous rows.
    """

    survival_probability: float = param(0.99, gt=0, le=1)
    max_detection_probability: float = param(0.99, gt=0, lt=1)
    birth_weight: float = param(0.0, ge=0)
    prune_threshold: float = param(1e-5, gt=0, lt=1)
    merge_threshold: float = param(4.0, ge=0)
    max_components: int = param(100, ge=1)
    use_identities: bool = True


@register_estimator
class GMPHD:
    """Gaussian-mixture PHD filter of the anonymous GPS rows (Vo & Ma 2006).

    Uses: GNSS rows, anonymous or identified (one PHD per vehicle, `use_identities`), and
    odometry where they are identified (with anonymous rows it is left aside); not the radar.
    """

    name: ClassVar[str] = "gm-phd"
    bound: ClassVar[str | None] = "kf-known-da"
    summary: ClassVar[str] = "Gaussian-mixture PHD filter (Vo & Ma 2006) of anonymous GPS rows"
    Params: ClassVar[type[Params]] = GMPHDParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "zhang2016-cv"
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("anonymous-position", "gnss-position"), "odometry": ("odometry",)}

    def __init__(self, setup: Setup, params: GMPHDParams, rng: np.random.Generator) -> None:
        self.setup = setup
        self.params = params
        dx = setup.vehicle_layout.dim
        self.dx = dx
        self.F = setup.vehicle_motion.transition_matrix(setup.dt)
        Q = setup.vehicle_motion.noise_covariance(setup.dt)
        self.Q = Q[0] if Q.ndim == 3 else Q
        sensor = setup.sensors.get("gnss")
        cols = list(getattr(sensor, "state_indices", setup.vehicle_layout.position))
        self.position = np.asarray(setup.vehicle_layout.position, dtype=np.int64)
        self.H = np.zeros((len(cols), dx))
        self.H[np.arange(len(cols)), cols] = 1.0
        self.p_d = min(setup.detection_probability, params.max_detection_probability)
        self.kappa = 0.0
        if setup.clutter_rate > 0 and setup.clutter_region is not None:
            area = float(np.prod(np.diff(setup.clutter_region, axis=1)))
            self.kappa = setup.clutter_rate / area
        self.labelled = params.use_identities and getattr(sensor, "name", "") == "gnss-position"
        odometry = setup.sensors.get("odometry")
        self.H_odo = None if odometry is None else odometry.observation_matrix(dx)
        # odometry names its vehicle: it has nowhere to go when the PHD is not per vehicle
        self.left_aside: tuple[str, ...] = ("odometry",) if odometry is not None and not self.labelled else ()
        self.mixture: Mixture | None = None
        self._last_rows: tuple[FloatArray, FloatArray] | None = None
        self._present: IntArray = np.zeros(0, dtype=np.int64)   # the vehicles of the last step

    def _update_odometry(self, frame: Frame, previous: Mixture, predicted: Mixture) -> Mixture:
        """Each vehicle's odometry row, fused into the components of its label (docs/gm_phd.md).

        As `gnss-kf` does it: only for a vehicle connected at k − 1 and k with exactly one
        row, each component by stochastic cloning from the component it was predicted from
        (`gaussian.kf_update_relative`). The row is that vehicle's for sure, so it moves the
        vehicle's PHD mass between its components and never changes the total:
        w_j ← W w_j q_j / Σ_l w_l q_l over the components l of the label, W = Σ_l w_l.
        """
        odometry = frame.batches.get("odometry")
        if not self.labelled or self.H_odo is None or odometry is None or not len(odometry):
            return predicted
        subjects, counts = np.unique(odometry.subject, return_counts=True)
        once = counts == 1
        moving = subjects[once & np.isin(subjects, self._present) & np.isin(subjects, frame.vehicles)]
        comp = np.flatnonzero(np.isin(predicted.labels, moving))
        if comp.size == 0:
            return predicted
        comp = comp[np.argsort(predicted.labels[comp], kind="stable")]      # grouped by label
        label = predicted.labels[comp]
        order = np.argsort(odometry.subject, kind="stable")
        row = order[np.searchsorted(odometry.subject[order], label)]
        updated, _, log_q = kf_update_relative(Gaussians(previous.mean[comp], previous.cov[comp]),
                                               Gaussians(predicted.mean[comp], predicted.cov[comp]), self.F,
                                               odometry.z[row], self.H_odo, odometry.cov[row])
        starts = np.r_[0, np.flatnonzero(np.diff(label)) + 1]
        of = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, label.size]))
        log_w = predicted.log_w[comp]
        log_total = np.logaddexp.reduceat(log_w, starts)                      # log W per label
        log_norm = np.logaddexp.reduceat(log_w + log_q, starts)               # log Σ_l w_l q_l
        out = Mixture(predicted.log_w.copy(), predicted.mean.copy(), predicted.cov.copy(), predicted.label)
        out.log_w[comp] = log_w + log_q - log_norm[of] + log_total[of]
        out.mean[comp], out.cov[comp] = updated.mean, updated.cov
        return out

    def _initial(self, frame: Frame) -> Mixture:
        prior = self.setup.vehicle_prior
        ids = prior.ids[np.isin(prior.ids, frame.vehicles)]
        if ids.size == 0:
            return Mixture.empty(self.dx)
        p = prior.take(ids)
        predicted = predict_steps(Gaussians(p.mean, p.cov), self.setup.vehicle_motion, self.setup.dt,
                                  frame.k)
        return Mixture(np.zeros(ids.size), predicted.mean, predicted.cov, ids if self.labelled else None)

    def _births(self) -> Mixture:
        if self.params.birth_weight <= 0 or self._last_rows is None or self._last_rows[0].size == 0:
            return Mixture.empty(self.dx)
        z, R = self._last_rows
        mean = z @ self.H                                                     # [z, 0]
        cov = np.repeat(default_birth_cov(self.setup)[None], z.shape[0], 0)
        cols = np.flatnonzero(self.H.any(axis=0))
        cov[:, cols[:, None], cols[None, :]] = R
        # birth at the previous step, predicted to this one
        predicted = Gaussians(mean @ self.F.T, symmetrize(self.F @ cov @ self.F.T + self.Q))
        return Mixture(np.full(z.shape[0], np.log(self.params.birth_weight)),
                       predicted.mean, predicted.cov)

    def _entry_births(self, frame: Frame, predicted: Mixture, z: FloatArray, R: FloatArray,
                      subject: IntArray) -> tuple[Mixture, IntArray]:
        """Births of the vehicles that connected this step, and the rows they take (docs/gm_phd.md).

        With identified rows, every connected vehicle that names a row and has no component
        of its label is born on that row: it may have connected without a row, or lost its
        components to pruning in an outage. With anonymous rows, the fusion centre knows how
        many vehicles connected, not which rows are theirs: the rows left over by an optimal
        assignment of the rows to the predicted components of weight ≥ 0.5 (squared
        Mahalanobis cost over every measured component) are the unexplained ones, and the
        farthest of them (from every component) seed one component of weight 1 each, the
        row itself as the state (`default_birth_cov` where the row does not measure a
        component). Those rows are already explained by their birth and are left out of the update.
        """
        if self.labelled:
            # the rows that name a connected vehicle without a component of its label: one
            # that connected without a row (it is born on its first), or whose components
            # were pruned in an outage — not only those that connected this step
            rows = np.flatnonzero(np.isin(subject, frame.vehicles) & ~np.isin(subject, predicted.labels))
            rows = rows[np.unique(subject[rows], return_index=True)[1]]   # one row per vehicle
            return self._born_on(rows, z, R, subject[rows]), rows
        known = self._present if self.mixture is not None else self.setup.vehicle_prior.ids
        n_new = np.count_nonzero(~np.isin(frame.vehicles, known))
        if n_new == 0 or z.shape[0] == 0:
            return Mixture.empty(self.dx), np.zeros(0, dtype=np.int64)
        strong = predicted.take(predicted.log_w >= np.log(0.5))
        S = symmetrize((self.H @ strong.cov @ self.H.T)[None] + R[:, None])           # (M, J, dz, dz)
        r = z[:, None, :] - (strong.mean @ self.H.T)[None]
        cost = np.einsum("mji,mji->mj", r, np.linalg.solve(S, r[..., None])[..., 0])
        rows = unexplained_rows(cost, n_new)
        return self._born_on(rows, z, R, None), rows

    def _born_on(self, rows: IntArray, z: FloatArray, R: FloatArray, label: IntArray | None) -> Mixture:
        """Components of weight 1 at `rows`: the row as the state, `default_birth_cov` where
        the row does not measure a component."""
        cov = np.repeat(default_birth_cov(self.setup)[None], rows.size, 0)
        cols = np.flatnonzero(self.H.any(axis=0))
        cov[:, cols[:, None], cols[None, :]] = R[rows]
        return Mixture(np.zeros(rows.size), z[rows] @ self.H, cov, label)

    def step(self, frame: Frame) -> Estimate:
        p = self.params
        gnss = frame.batches.get("gnss")
        dz = self.H.shape[0]
        z = gnss.z if gnss is not None else np.zeros((0, dz))
        R = gnss.cov if gnss is not None else np.zeros((0, dz, dz))
        subject = gnss.subject if gnss is not None else np.zeros(0, dtype=np.int64)
        if self.mixture is None:
            mixture = self._initial(frame)
        else:
            m = self.mixture
            # prediction, Table I step 2: w ← p_S w, m ← F m, P ← F P Fᵀ + Q, plus births
            survived = Mixture(m.log_w + np.log(p.survival_probability), m.mean @ self.F.T,
                               symmetrize(self.F @ m.cov @ self.F.T + self.Q), m.label)
            survived = self._update_odometry(frame, m, survived)
            mixture = Mixture.concatenate([survived, self._births()])
        born, taken = self._entry_births(frame, mixture, z, R, subject)
        self._present = np.array(frame.vehicles, dtype=np.int64)
        rest = np.ones(z.shape[0], dtype=bool)
        rest[taken] = False
        try:
            updated = (phd_update(mixture, z[rest], R[rest], self.H, self.p_d, self.kappa,
                                  subject[rest] if self.labelled else None) if len(mixture) else mixture)
            updated = Mixture.concatenate([updated, born])   # births already hold their rows
            self.mixture = merge_components(updated, p.prune_threshold, p.merge_threshold,
                                            p.max_components)
        except np.linalg.LinAlgError:
            eig = np.linalg.eigvalsh(mixture.cov) if len(mixture) else np.ones((1, 1))
            raise EstimatorError(self.name, "a mixture component's covariance lost positive definiteness in "
                                 f"the Joseph update (predicted variances {eig.min():.3g} … {eig.max():.3g}, "
                                 "too far from the rows' for float64)") from None
        self._last_rows = (np.array(z), np.array(R))
        return self._extract(frame)

    def _extract(self, frame: Frame) -> Estimate:
        m = self.mixture
        assert m is not None
        n = frame.vehicles.size
        weights = np.exp(m.log_w)
        info: dict[str, Any] = {
            "set_valued": not self.labelled,
            "cardinality": float(weights.sum()),
            "n_components": len(m),
            "n_extracted_vo_ma": int(np.round(weights[weights > 0.5]).sum()),
        }
        if n == 0:
            return Estimate(StateSet.empty(self.dx), None, info)
        if len(m) == 0:  # nothing left to extract: broad beliefs (never seen in Zhang's setting)
            cov = np.repeat(default_birth_cov(self.setup)[None], n, 0)
            return Estimate(StateSet(np.sort(frame.vehicles), np.zeros((n, self.dx)), cov), None, info)
        ids = np.sort(frame.vehicles)
        if self.labelled:   # each vehicle's heaviest component; broad where it has none left
            mean = np.zeros((n, self.dx))
            cov = np.repeat(default_birth_cov(self.setup)[None], n, 0)
            order = np.lexsort((-m.log_w, m.labels))                   # by label, heaviest first
            first = order[np.r_[True, np.diff(m.labels[order]) != 0]]
            at = np.searchsorted(ids, m.labels[first])
            ok = (at < n) & (ids[np.minimum(at, n - 1)] == m.labels[first])
            mean[at[ok]], cov[at[ok]] = m.mean[first[ok]], m.cov[first[ok]]
            return Estimate(checked_states(self.name, "vehicle", ids, mean, cov), None, info)
        picks = extract_count(m, n, self.position, self.params.merge_threshold)
        vehicles = checked_states(self.name, "vehicle", ids, m.mean[picks], m.cov[picks])
        return Estimate(vehicles, None, info)
