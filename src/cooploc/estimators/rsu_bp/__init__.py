"""`rsu-bp`: centralized particle BP with BP data association at the road-side unit.

Paper: M. Fröhle, C. Lindberg, H. Wymeersch, "Cooperative Localization of Vehicles
without Inter-vehicle Measurements", IEEE WCNC 2018, §III–V. Every vehicle s sends its
GNSS fix and its anonymous, shuffled V2F detections z_m = H f_k − H x_s + w (eq. (1))
to the RSU, which runs loopy BP on the factor graph of eq. (9) (Fig. 2), one time step
after the other (filtering), on particle beliefs (§IV-B, N_p per state). Per step:
prediction (10)–(11); measurement evaluation (14) from the kernel over all particle
pairs (`rsu_bp.kernel`: computed once, reused; in the separable form one exponential per
pair of a vehicle's and a feature's particles, whatever the rows); data association (15)–(20) by
`association.bp_association`; I iterations of measurement correction (21)–(24);
beliefs (25)–(26) as log-weights, resampled when N_eff < `resample_threshold` · N_p.
BP beliefs drop the vehicle–feature correlation that `oracle-kf` keeps, so rsu-bp stays
above the known-association bound.

The messages written out, the complexity, and the choices the paper leaves open (vehicle
births, feature initialisation, normalised messages, the shrinkage move after
resampling, vanishing messages, ignored rows): docs/rsu_bp.md.

Features not known in advance (`features`: "unknown", or "auto" on a setup without a
feature prior, e.g. the sumo-* and brambilla-* scenarios): potential features with
existence probabilities, births, survival, misses only within the sensing range,
pruning (Meyer et al. 2018) in `rsu_bp.tracking` (existence weights in
`rsu_bp.existence`). It is a second code path: with a feature prior (K known) the
paper's algorithm above runs unchanged, bit for bit. In the unknown-feature path the
vehicles' beliefs φχ are their own GNSS tracks and their particles are drawn from a
proposal near the posterior (`rsu_bp.vehicles.posterior_samples`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from cooploc.association import association_weights, bp_association, decide, padded_groups
from cooploc.errors import ConfigError
from cooploc.estimators.base import birth_beliefs, checked_states, predict_steps
from cooploc.estimators.gnss_kf import GnssKF, GnssKFParams
from cooploc.estimators.rsu_bp.kernel import SeparableKernel
from cooploc.estimators.rsu_bp.tracking import FeatureTracker
from cooploc.estimators.rsu_bp.vehicles import posterior_samples
from cooploc.gaussian import Gaussians, gaussian_logpdf, kf_update
from cooploc.params import Params, param
from cooploc.particles import (
    Particles,
    effective_sample_size,
    log_sum_exp,
    normalize_log_weights,
    pair_kernel,
    pair_kernel_log_sum,
    propagate_linear,
    resample,
    sample_gaussians,
    shrinkage_move,
    systematic_resample,
    weighted_moments,
)
from cooploc.registry import register_estimator
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, Setup, StateSet, lookup_ids

__all__ = ["RsuBP", "RsuBPParams"]

#: ESS below this share of N_p is reported as degenerate in `Estimate.info`.
DEGENERACY_SHARE = 0.1


@dataclass(frozen=True)
class RsuBPParams(Params):
    """Parameters of `rsu-bp` (defaults: Fröhle 2018 §V-A).

    Attributes
    ----------
    n_particles : N_p, particles per vehicle and per feature (paper: 600).
    n_da_iterations : P, loopy-BP iterations of the data association (paper: 5).
    n_correction_iterations : I, measurement-correction iterations (paper: 1).
    resample_threshold : resample a belief when N_eff < threshold · N_p (1: every step).
    association_threshold : a V2F row is attributed to its MAP feature only if that
        feature's marginal probability is at least this (else -1) in `v2f_association`.
    shrinkage_move : after resampling, move the particles by a Liu–West kernel step
        (`particles.shrinkage_move`: same mean and covariance, fresh diversity).
    kernel_memory_mb : store the pair kernel of a step if it fits in this many MB,
        else recompute it for each use.
    feature_init : "measurements" — draw the feature particles around the first V2F
        detections (the paper's footnote 1); "prior" — sample `Setup.feature_prior`.

    The unknown-feature model (`rsu_bp.tracking`; Meyer et al. 2018 for existence,
    births and pruning):

    features : "known" — the paper's K features of `Setup.feature_prior`; "unknown" —
        potential features born from the V2F rows; "auto" — "known" when the setup has
        a feature prior, else "unknown".
    survival_probability : p_s, a potential feature survives one step (Meyer: 0.999).
    birth_density : μ_b f_b, expected new features per m² and step (uniform in position).
    birth_velocity_std : σ_b of the birth intensity on the non-position components (m/s).
    max_detection_probability : P_D is min(`Setup.detection_probability`, this): with
        P_D = 1 one undetected step would delete a feature outright.
    gate_probability : a feature–row pair enters the BP inside this χ² ellipsoid.
    prune_threshold : potential features with existence below this are dropped (Meyer:
        10⁻³); rows start a feature only with at least this existence.
    existence_threshold : features with existence at least this are reported (0.5).
    feature_messages : what a vehicle's message to a potential feature carries (`rsu_bp.tracking`
        step 5): "fixes" — its GNSS fix of the step through the rows, every step's added;
        "tracks" — its GNSS track through the rows, each vehicle's latest message
        replacing its previous one (`rsu_bp.map_messages`; measured worse on the sumo-*
        presets, docs/rsu_bp.md).
    """

    n_particles: int = param(600, ge=2)
    n_da_iterations: int = param(5, ge=1)
    n_correction_iterations: int = param(1, ge=1)
    resample_threshold: float = param(1.0, ge=0, le=1)
    association_threshold: float = param(0.5, ge=0, le=1)
    shrinkage_move: bool = True
    kernel_memory_mb: float = 512.0
    feature_init: str = param("measurements", choices=("measurements", "prior"))
    features: str = param("auto", choices=("auto", "known", "unknown"))
    survival_probability: float = param(0.999, gt=0, le=1)
    birth_density: float = param(1e-5, gt=0, finite=True)
    birth_velocity_std: float = param(2.0, gt=0, finite=True)
    max_detection_probability: float = param(0.99, gt=0, le=1)
    gate_probability: float = param(0.9999, gt=0, lt=1)
    prune_threshold: float = param(1e-3, gt=0, lt=1)
    existence_threshold: float = param(0.5, gt=0, le=1)
    feature_messages: str = param("fixes", choices=("fixes", "tracks"))

    def validate(self) -> None:
        # no finiteness asked: inf means "always store the kernel"
        self.require(self.kernel_memory_mb >= 0, "kernel_memory_mb", "be >= 0")


@register_estimator
class RsuBP:
    """Nonparametric BP at the RSU over all vehicles and features, with BP association.

    Uses: identified GNSS rows and anonymous V2F rows. Consistency: BP beliefs drop the
    vehicle–feature correlation every step, so its covariances are optimistic where
    that correlation matters (long runs); on short froehle2018 runs its time-averaged
    NEES stays inside the χ² band (tests/test_consistency.py).
    """

    name: ClassVar[str] = "rsu-bp"
    bound: ClassVar[str | None] = "oracle-kf"
    summary: ClassVar[str] = (
        "centralized particle BP with loopy-BP data association at the road-side unit "
        "(Fröhle et al. 2018)"
    )
    Params: ClassVar[type[Params]] = RsuBPParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "froehle2018"
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("gnss-position",), "v2f": ("relative-position",), "odometry": ("odometry",)}

    def __init__(self, setup: Setup, params: RsuBPParams, rng: np.random.Generator) -> None:
        self.setup, self.params, self.rng = setup, params, rng
        self.dx = setup.vehicle_layout.dim
        self.Fx = setup.vehicle_motion.transition_matrix(setup.dt)
        self.gnss = setup.sensors.get("gnss")
        self.v2f = setup.sensors.get("v2f")
        prior = setup.feature_prior
        track = setup.feature_layout is not None and prior is not None and len(prior) > 0
        if track and self.v2f is None:
            track = False  # features are observed only through V2F rows
        self.df = setup.feature_layout.dim if setup.feature_layout is not None else 0
        if track:
            order = np.argsort(prior.ids, kind="stable")
            self.feature_ids: IntArray = prior.ids[order]
            self._feature_prior = Gaussians(prior.mean[order], prior.cov[order])
            self.Ff = setup.feature_motion.transition_matrix(setup.dt)
        else:
            self.feature_ids = np.zeros(0, dtype=np.int64)
        self.tracker: FeatureTracker | None = None     # the unknown-feature model, if used
        if params.features == "known" or (params.features == "auto" and track):
            pass
        elif self.v2f is not None and setup.feature_layout is not None:
            self.feature_ids = np.zeros(0, dtype=np.int64)
            track = False
            self.tracker = True  # built below, once the clutter intensity is known
        self.features: Particles | None = None        # None until initialised from V2F rows
        self.feature_gauss: Gaussians | None = None   # predicted prior until then
        self.vehicle_ids: IntArray = np.zeros(0, dtype=np.int64)
        N = params.n_particles
        self.vehicles = Particles(np.zeros((0, N, self.dx)), np.zeros((0, N)))
        self.last_k: int | None = None
        self._kernel_buffer = np.zeros(0, dtype=np.float32)   # the pair kernel's values, reused
        self._fixed_noise: dict[str, FloatArray] = {}         # Q of state-independent motion noise
        self.p_d = float(setup.detection_probability)
        self.clutter_intensity = 0.0
        if setup.clutter_rate > 0:
            if setup.clutter_region is None:
                raise ConfigError("rsu-bp: Setup.clutter_rate > 0 needs Setup.clutter_region "
                                  "(the clutter density is uniform over it)")
            region = np.asarray(setup.clutter_region)
            self.clutter_intensity = setup.clutter_rate / float(np.prod(region[:, 1] - region[:, 0]))
        if self.tracker is not None:
            self.tracker = FeatureTracker(setup, params, self.clutter_intensity)
            self.own = GnssKF(setup, GnssKFParams(), rng)
            # the reported beliefs, predicted and updated with GNSS (odometry) like a track:
            # what a vehicle without V2F rows reports (see `_step_unknown`)
            self.carried = GnssKF(setup, GnssKFParams(), rng)
        # odometry reaches the vehicles only through the city mode's GNSS tracks
        self.left_aside: tuple[str, ...] = (
            ("odometry",) if self.tracker is None and "odometry" in setup.sensors else ())

    # ------------------------------------------------------------------ step

    def step(self, frame: Frame) -> Estimate:
        steps = frame.k - self.last_k if self.last_k is not None else None
        self.last_k = frame.k
        if self.tracker is not None:
            return self._step_unknown(frame, steps)
        gnss_used = self._vehicles_sync_predict(frame, steps)
        self._features_predict(frame, steps)
        log_phi_chi = self.vehicles.log_weights + self._gnss_loglik(frame, gnss_used)  # φ χ
        info: dict[str, Any] = {}
        v2f = frame.batches.get("v2f")
        n_rows = len(v2f) if v2f is not None else 0
        decided = np.full(n_rows, -1, dtype=np.int64)
        rows = np.zeros(0, dtype=np.int64)
        if n_rows and self.feature_ids.size and len(self.vehicles):
            rows = np.flatnonzero(lookup_ids(self.vehicle_ids, v2f.sensor)[1])
        log_bx = log_phi_chi
        if self.features is None and self.feature_ids.size and self.params.feature_init == "prior":
            g = self.feature_gauss
            self.features = sample_gaussians(g.mean, g.cov, self.params.n_particles, self.rng)
            self.feature_gauss = None
        if rows.size and self.features is None:
            self._features_init(v2f.select(rows), log_phi_chi)
            info["features_initialised"] = True
        elif rows.size:
            log_bx, log_bf, assoc = self._bp_update(v2f.select(rows), log_phi_chi)
            self.features = Particles(self.features.samples, normalize_log_weights(log_bf)[0])
            decided[rows] = assoc.pop("decided")
            info.update(assoc)
        self.vehicles = Particles(self.vehicles.samples, normalize_log_weights(log_bx)[0])
        info["v2f_association"] = decided
        # the feature ids are labels this filter gives features that all share one prior:
        # score them as tracks (the true feature most of their rows came from)
        info["v2f_track"] = decided
        info["v2f_discarded"] = int((decided < 0).sum())
        estimate = self._estimate(info)
        self._resample()
        return estimate

    def _step_unknown(self, frame: Frame, steps: int | None) -> Estimate:
        """One step with potential features (`rsu_bp.tracking`) instead of the K known ones.

        φ_s χ_s is each vehicle's own GNSS track (`gnss-kf`), sampled afresh every step;
        the features' messages weight the samples and are not carried into the track.

        A vehicle without V2F rows reports its last reported belief predicted to this step
        and updated with this step's GNSS (and odometry) rows (`self.carried`, a second
        `gnss-kf` whose beliefs are replaced by the reported ones after every step), not
        its GNSS-only track: what the features told it earlier is kept, as in the joint
        filter, and counted once, since the next step with rows starts again from the
        GNSS-only track.
        """
        own = self.own.step(frame).vehicles
        carried = self.carried.step(frame).vehicles
        self.tracker.predict(steps)
        N = self.params.n_particles
        v2f = frame.batches.get("v2f")
        n_rows = len(v2f) if v2f is not None else 0
        track = np.full(n_rows, -1, dtype=np.int64)
        rows = np.zeros(0, dtype=np.int64)
        if n_rows and len(own):
            rows = np.flatnonzero(lookup_ids(own.ids, v2f.sensor)[1])
        info: dict[str, Any] = {}
        mean, cov = carried.mean.copy(), carried.cov.copy()     # both filters hold the same ids
        ess = np.full(len(own), float(N))
        if rows.size:
            # particles only for vehicles with rows: the others' belief is their own track
            active = np.unique(lookup_ids(own.ids, v2f.sensor[rows])[0])
            slot = np.full(len(own), -1, dtype=np.int64)
            slot[active] = np.arange(active.size)
            messages, track[rows], found = self.tracker.update(
                own.ids, own.mean, own.cov, v2f.select(rows), frame.batches.get("gnss"))
            info.update(found)
            messages = messages.on(slot, active.size)
            samples, log_w = posterior_samples(
                StateSet(own.ids[active], own.mean[active], own.cov[active]), messages, N, self.rng)
            mean[active], cov[active] = weighted_moments(Particles(samples, log_w))
            ess[active] = effective_sample_size(log_w)
        info["v2f_association"] = track
        info["v2f_track"] = track
        info["v2f_discarded"] = int((track < 0).sum())
        info["vehicle_ess"] = ess
        info["degenerate"] = bool(len(own) and ess.min() < DEGENERACY_SHARE * N)
        features, info["feature_existence"] = self.tracker.estimate()
        vehicles = checked_states(self.name, "vehicle", own.ids, mean, cov)
        self.carried.vehicles.beliefs = Gaussians(vehicles.mean, vehicles.cov)
        return Estimate(vehicles, features, info)

    # ------------------------------------------------------------ vehicles

    def _vehicles_sync_predict(self, frame: Frame, steps: int | None) -> np.ndarray:
        """Drop leaving vehicles, predict the others (11), birth entering ones.

        Returns the mask (over the sorted present ids) of vehicles born this step
        whose first GNSS fix is already in their particles.
        """
        present = np.unique(frame.vehicles)
        keep = np.isin(self.vehicle_ids, present)
        ids, cont = self.vehicle_ids[keep], self.vehicles.take(keep)
        if len(cont) and steps:
            for _ in range(steps):
                Q = self._process_noise("vehicle", cont)
                cont = propagate_linear(cont, self.Fx, Q, self.rng)
        born_ids = np.setdiff1d(present, ids)
        used = np.zeros(born_ids.size, dtype=bool)
        N = self.params.n_particles
        born = Particles(np.zeros((0, N, self.dx)), np.zeros((0, N)))
        if born_ids.size:
            belief = birth_beliefs(self.setup, born_ids, frame)
            belief, used = self._first_fix(belief, born_ids, frame.batches.get("gnss"))
            born = sample_gaussians(belief.mean, belief.cov, N, self.rng)
        all_ids = np.concatenate([ids, born_ids])
        order = np.argsort(all_ids, kind="stable")
        self.vehicle_ids = all_ids[order]
        self.vehicles = Particles(np.concatenate([cont.samples, born.samples])[order],
                                  np.concatenate([cont.log_weights, born.log_weights])[order])
        return np.concatenate([np.zeros(ids.size, bool), used])[order]

    def _first_fix(self, belief: Gaussians, ids: IntArray, gnss: Batch | None
                   ) -> tuple[Gaussians, np.ndarray]:
        """Kalman-update birth beliefs with each vehicle's first GNSS row, where it has one."""
        used = np.zeros(ids.size, dtype=bool)
        if gnss is None or not len(gnss) or self.gnss is None:
            return belief, used
        row, found = lookup_ids(gnss.subject, ids)
        if not found.any():
            return belief, used
        H = self.gnss.observation_matrix(self.dx)
        post = kf_update(belief.take(found), gnss.z[row[found]], H, gnss.cov[row[found]])
        mean, cov = belief.mean.copy(), belief.cov.copy()
        mean[found], cov[found] = post.mean, post.cov
        return Gaussians(mean, cov), found

    def _gnss_loglik(self, frame: Frame, used: np.ndarray) -> FloatArray:
        """log χ_s(x_l) (n, N_p): every GNSS row of a present vehicle (eq. (8))."""
        out = np.zeros(self.vehicles.log_weights.shape)
        gnss = frame.batches.get("gnss")
        if gnss is None or not len(gnss) or self.gnss is None or not len(self.vehicles):
            return out
        pos, found = lookup_ids(self.vehicle_ids, gnss.subject)
        take = found & ~used[pos]
        if not take.any():
            return out
        s = pos[take]
        H = self.gnss.observation_matrix(self.dx)
        residual = gnss.z[take][:, None, :] - self.vehicles.samples[s] @ H.T      # (R, N_p, dz)
        loglik = gaussian_logpdf(residual, gnss.cov[take][:, None])               # (R, N_p)
        np.add.at(out, s, loglik)
        return out

    def _process_noise(self, kind: str, belief: Particles) -> FloatArray:
        """Q of one step of the vehicles' or features' motion: at the belief's mean where
        the model's noise turns with the state, else the model's fixed Q, computed once."""
        motion = getattr(self.setup, f"{kind}_motion")
        if motion.state_dependent_noise:
            return motion.noise_covariance(self.setup.dt, np.einsum("nl,nld->nd", belief.weights,
                                                                    belief.samples))
        if kind not in self._fixed_noise:
            self._fixed_noise[kind] = motion.noise_covariance(self.setup.dt)
        return self._fixed_noise[kind]

    # ------------------------------------------------------------ features

    def _features_predict(self, frame: Frame, steps: int | None) -> None:
        """α_k (10); before initialisation, the Gaussian prior predicted to this step."""
        if not self.feature_ids.size:
            return
        motion, dt = self.setup.feature_motion, self.setup.dt
        if self.features is None:
            if self.feature_gauss is None:   # the prior holds at step 0
                self.feature_gauss = predict_steps(self._feature_prior, motion, dt, frame.k)
            elif steps:
                self.feature_gauss = predict_steps(self.feature_gauss, motion, dt, steps)
            return
        for _ in range(steps or 0):
            self.features = propagate_linear(self.features, self.Ff,
                                             self._process_noise("feature", self.features), self.rng)

    def _features_init(self, v2f: Batch, log_phi_chi: FloatArray) -> None:
        """Draw feature particles around the V2F detections (see module docstring)."""
        N, K = self.params.n_particles, self.feature_ids.size
        Hx = self.v2f.observation_matrix(self.dx)
        pos_f = np.asarray(self.v2f.state_indices)
        s_row = lookup_ids(self.vehicle_ids, v2f.sensor)[0]
        vehicles = Particles(self.vehicles.samples, normalize_log_weights(log_phi_chi)[0])
        mean, cov = weighted_moments(vehicles)
        Hp = Hx @ cov @ Hx.T                                                       # (n, dz, dz)
        anchor = s_row[np.argmin(np.trace(Hp, axis1=1, axis2=2)[s_row])]
        anchor_rows = self._corroborated(v2f, s_row, anchor, mean @ Hx.T, Hp)
        # one row per particle: row k of the anchor for feature k, else any row
        choice = np.empty((K, N), dtype=np.int64)
        for k in range(K):
            choice[k] = anchor_rows[k] if k < anchor_rows.size else self.rng.integers(0, len(v2f), N)
        s = s_row[choice]                                                        # (K, N)
        idx = systematic_resample(vehicles.log_weights, self.rng)                # (n, N)
        x = self.vehicles.samples[s, idx[s, np.arange(N)[None, :]]]              # (K, N, dx)
        L = np.linalg.cholesky(v2f.cov[choice])                                   # (K, N, dz, dz)
        w = np.einsum("knde,kne->knd", L, self.rng.standard_normal((*choice.shape, pos_f.size)))
        p = x @ Hx.T + v2f.z[choice] + w                                          # H f = H x + z + w
        # the rest of the state from the Gaussian prior conditioned on the position
        prior = self.feature_gauss
        rest = np.setdiff1d(np.arange(self.df), pos_f)
        f = np.empty((K, N, self.df))
        f[:, :, pos_f] = p
        if rest.size:
            P_pp = prior.cov[:, pos_f][:, :, pos_f]
            P_rp = prior.cov[:, rest][:, :, pos_f]
            P_rr = prior.cov[:, rest][:, :, rest]
            gain = np.linalg.solve(P_pp, np.swapaxes(P_rp, 1, 2)).transpose(0, 2, 1)   # P_rp P_pp⁻¹
            cond_mean = prior.mean[:, None, rest] + np.einsum(
                "kre,kne->knr", gain, p - prior.mean[:, None, pos_f])
            cond_cov = P_rr - gain @ np.swapaxes(P_rp, 1, 2)
            noise = sample_gaussians(np.zeros((K, rest.size)), 0.5 * (cond_cov + np.swapaxes(cond_cov, 1, 2)),
                                     N, self.rng).samples
            f[:, :, rest] = cond_mean + noise
        self.features = Particles.uniform(f)
        self.feature_gauss = None

    @staticmethod
    def _corroborated(v2f: Batch, s_row: IntArray, anchor: int, pos: FloatArray, pos_cov: FloatArray
                      ) -> IntArray:
        """Rows of `anchor`, most corroborated by the other vehicles' rows first.

        Row r places a feature at g_r = H x̂_s + z_r, covariance C_r = H P_s Hᵀ + W_r. A
        real feature is seen by several vehicles, clutter by one: the score of an anchor
        row is log Σ_{r' of other vehicles} N(g_r − g_r'; 0, C_r + C_r').
        """
        rows = np.flatnonzero(s_row == anchor)
        others = np.flatnonzero(s_row != anchor)
        if not others.size or rows.size < 2:
            return rows
        g = pos[s_row] + v2f.z                                                    # (R, dz)
        C = pos_cov[s_row] + v2f.cov
        diff = g[rows][:, None, :] - g[others][None, :, :]
        score = log_sum_exp(gaussian_logpdf(diff, C[rows][:, None] + C[others][None, :]), axis=1)
        return rows[np.argsort(-score, kind="stable")]

    # ------------------------------------------------------------ BP update

    def _bp_update(self, v2f: Batch, log_phi_chi: FloatArray
                   ) -> tuple[FloatArray, FloatArray, dict[str, Any]]:
        """Steps 2–6 on the V2F rows of present vehicles: log-beliefs and association."""
        prm, p_d = self.params, self.p_d
        X, Fp = self.vehicles.samples, self.features.samples
        S, K, N = X.shape[0], Fp.shape[0], prm.n_particles
        R = len(v2f)
        Hx, Hf = self.v2f.observation_matrix(self.dx), self.v2f.observation_matrix(self.df)
        s_row = lookup_ids(self.vehicle_ids, v2f.sensor)[0]                       # (R,)
        # blocks b = r K + k: row r (of vehicle s_r) against feature k
        s_b, k_b = np.repeat(s_row, K), np.tile(np.arange(K), R)
        z_b, cov_b = np.repeat(v2f.z, K, axis=0), np.repeat(v2f.cov, K, axis=0)
        Hf_p, Hx_p = Fp @ Hf.T, X @ Hx.T                                          # H f_j, H x_l
        a_b, c_b = Hf_p[k_b], Hx_p[s_b]
        log_wx = normalize_log_weights(log_phi_chi)[0]                            # ρ^(0) = φχ
        index, mask = padded_groups(s_row, S)
        # G per block, stored once and reused (docs/rsu_bp.md "Where the time goes"): in the
        # separable form when each vehicle's rows share one W (one exponential per pair of a
        # vehicle and a feature, `rsu_bp.kernel`), else directly (one per pair of each block)
        separable = bool((v2f.cov == v2f.cov[index[s_row, 0]]).all())
        active = np.flatnonzero(mask.any(axis=1))
        n_values = active.size * K * N * N if separable else s_b.size * N * N
        store = n_values * 4 <= prm.kernel_memory_mb * 2**20
        if store and separable:
            groups = (index[active][:, None, :] * K + np.arange(K)[:, None]).reshape(-1, index.shape[1])
            # (and β's sums over the vehicle particles from the pass that computes it)
            G, log_lx = SeparableKernel.build(z_b, cov_b, Hf_p, Hx_p, k_b, s_b, groups,
                                              np.repeat(mask[active], K, axis=0),
                                              np.exp(log_wx)[s_b], self._buffer(n_values))
            over_x, over_f = G.log_sum_over_second, G.log_sum_over_first
        elif store:
            G = pair_kernel(z_b, cov_b, a_b, c_b, self._buffer(n_values))
            over_x, over_f = G.log_sum_over_second, G.log_sum_over_first
            log_lx = over_x(np.exp(log_wx)[s_b])
        else:
            def over_x(weights: FloatArray) -> FloatArray:      # log Σ_l w_{b,l} G[b, j, l]
                return pair_kernel_log_sum(z_b, cov_b, a_b, c_b, weights)

            def over_f(weights: FloatArray) -> FloatArray:      # log Σ_j w_{b,j} G[b, j, l]
                return pair_kernel_log_sum(-z_b, cov_b, c_b, a_b, weights)

            log_lx = over_x(np.exp(log_wx)[s_b])                                  # (B, N_f)
        # Step 2: β_{k,s}(m) = Σ_j α_j Σ_l (φχ)_l G (14)
        log_beta = log_sum_exp(log_lx + self.features.log_weights[k_b], axis=1).reshape(R, K)
        # Steps 3–4: data association per vehicle (15)–(20), padded to (S, K, M_max)
        slot = np.empty(R, dtype=np.int64)
        slot[index[mask]] = np.nonzero(mask)[1]
        log_psi, log_missed, log_kappa = association_weights(
            log_beta[index].transpose(0, 2, 1), p_d, self.clutter_intensity)
        marg = bp_association(log_psi, log_missed, log_kappa, prm.n_da_iterations,
                              measurement_mask=mask)
        # log P_D ν_{m→k} per block: the weight of measurement m in γ and μ
        log_coef = np.log(p_d) + marg.log_nu[s_row, :, slot]                      # (R, K)
        with np.errstate(divide="ignore"):
            log_psi0 = np.log1p(-p_d) if p_d < 1 else -np.inf
        has_rows = mask.any(axis=1)

        def per_sensor(log_sums: FloatArray) -> FloatArray:
            """log[(1 − P_D) + P_D Σ_m ν_{m→k} sums] per (s, k) (21), (23); 0 without rows."""
            terms = (log_coef[:, :, None] + log_sums.reshape(R, K, -1))[index]     # (S, M, K, N)
            terms = np.where(mask[:, :, None, None], terms, -np.inf)
            total = np.logaddexp(log_psi0, log_sum_exp(terms, axis=1))               # (S, K, N)
            dead = ~np.isfinite(total.max(axis=2, initial=-np.inf))               # no information
            return np.where(has_rows[:, None, None] & ~dead[:, :, None], total, 0.0)

        # Step 5: measurement correction (21)–(24)
        log_alpha = self.features.log_weights                                     # (K, N)
        log_gamma = per_sensor(log_lx)                                            # (21), ρ^(0)
        for i in range(prm.n_correction_iterations):
            # α̃_{k,s} = α_k Π_{s'≠s} γ_{k,s'} (22)
            log_at = log_alpha[None] + log_gamma.sum(axis=0, keepdims=True) - log_gamma
            at = np.exp(normalize_log_weights(log_at)[0])                          # (S, K, N)
            log_mu = per_sensor(over_f(at[s_b, k_b]))                              # (23)
            if i + 1 == prm.n_correction_iterations:
                break
            # ρ_{k,s} = φ_s χ_s Π_{k'≠k} μ_{k',s} (24), then γ again (21)
            log_rho = log_wx[:, None] + log_mu.sum(axis=1, keepdims=True) - log_mu
            rho = np.exp(normalize_log_weights(log_rho)[0])
            log_gamma = per_sensor(over_x(rho[s_b, k_b]))
        # Step 6: beliefs (25)–(26)
        log_bf = log_alpha + log_gamma.sum(axis=0)
        log_bx = log_phi_chi + log_mu.sum(axis=1)
        chosen = decide(marg, prm.association_threshold)[s_row, slot]
        info = {
            "decided": np.where(chosen >= 0, self.feature_ids[np.maximum(chosen, 0)], -1),
            "association": {
                "feature_ids": self.feature_ids,
                "measurement": marg.measurement[s_row, slot],                     # (R, K)
                "clutter": marg.clutter[s_row, slot],                             # (R,)
            },
            "da_iterations": marg.iterations,
            "kernel_pairs": int(s_b.size * N * N),
            "kernel_stored": bool(store),
            "kernel_form": "separable" if separable else "direct",
        }
        return log_bx, log_bf, info

    def _buffer(self, size: int) -> np.ndarray:
        """A float32 buffer of at least `size` values for the pair kernel, kept from step to
        step (fresh zeroed pages of this size every step would cost more than the kernel)."""
        if self._kernel_buffer.size < size:
            self._kernel_buffer = np.empty(size, dtype=np.float32)
        return self._kernel_buffer

    # ------------------------------------------------------------ output

    def _estimate(self, info: dict[str, Any]) -> Estimate:
        N = self.params.n_particles
        v_mean, v_cov = weighted_moments(self.vehicles)
        vehicles = checked_states(self.name, "vehicle", self.vehicle_ids, v_mean, v_cov)
        v_ess = effective_sample_size(self.vehicles.log_weights)
        info["vehicle_ess"] = v_ess
        features = None
        if self.df and self.feature_ids.size:
            if self.features is None:
                f_mean, f_cov = self.feature_gauss.mean, self.feature_gauss.cov
                f_ess = np.zeros(0)
            else:
                f_mean, f_cov = weighted_moments(self.features)
                f_ess = effective_sample_size(self.features.log_weights)
            features = checked_states(self.name, "feature", self.feature_ids, f_mean, f_cov)
            info["feature_ess"] = f_ess
        elif self.df:
            features = StateSet.empty(self.df)
            info["feature_ess"] = np.zeros(0)
        ess = np.concatenate([v_ess, info["feature_ess"] if "feature_ess" in info else []])
        info["degenerate"] = bool(ess.size and ess.min() < DEGENERACY_SHARE * N)
        return Estimate(vehicles, features, info)

    def _resample(self) -> None:
        """Systematic resampling of the beliefs whose N_eff fell below the threshold."""
        share = self.params.resample_threshold
        for part in ("vehicles", "features"):
            belief = getattr(self, part)
            if belief is None or not len(belief):
                continue
            which = np.ones(len(belief), bool) if share >= 1.0 else (
                effective_sample_size(belief.log_weights) < share * belief.n_particles)
            belief = resample(belief, self.rng, which)
            if self.params.shrinkage_move:
                belief = shrinkage_move(belief, self.rng, which)
            setattr(self, part, belief)
