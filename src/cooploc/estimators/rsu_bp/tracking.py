"""The feature side of `rsu-bp` when the features are not known in advance.

The paper's model has K known features that every vehicle may see. A city has features
that appear and disappear and that each vehicle sees only within its sensing range, so
here the feature set is a multi-Bernoulli set of *potential features* (Meyer et al.,
"Message passing algorithms for scalable multitarget tracking", Proc. IEEE 2018), each a
Gaussian belief with an existence probability r (`existence` holds the weights). The
vehicles' beliefs φ_s χ_s (Fröhle eqs. (8), (11)) are their own GNSS tracks (the
estimator runs `gnss-kf` for them), sampled afresh each step (N_p particles per vehicle
with V2F rows). One step:

1. **Prediction** of every potential feature through the feature motion model (Fröhle
   (10)); r⁻ = p_s r with the survival probability p_s.
2. **Gating.** A feature–row pair enters the BP only if the row's predicted residual
   z − (H f̄ − H x̄_s) lies inside the `gate_probability` ellipsoid of W + H P_f Hᵀ + H P_s Hᵀ
   (candidates from a KD-tree over feature positions): the work is linear in the rows
   and the features near them, not in all pairs.
3. **Measurement evaluation** (Fröhle (14)) for gated pairs: β_{k,s}(m) =
   ∫∫ N(z_m; H f − H x, W) φχ(x) α_k(f) dx df = N(z_m; H f̄_k − H x̄_s, W + H P_k Hᵀ +
   H P_s Hᵀ), in closed form since both beliefs are Gaussian here (φχ is the vehicle's
   Kalman track). It is the limit of the paper's particle sum; a sum over N_p samples
   of a track metres wide would hold a handful of particles within a decimetre-precise
   row of a well-known feature and make β, and so the association, noisy exactly
   when the map is good.
4. **Data association with existence** per vehicle (`existence`: ψ, ψ(0), κ with the
   birth intensity λ_b; `association.bp_association`, Fröhle (15)–(20)). A feature out
   of the vehicle's range R_s (`RelativePosition.max_range`) has P(in range) ≈ 0 and
   so no miss; a feature in range with no gated row is a miss for that vehicle.
5. **Feature update** (Fröhle (21)): vehicle s's message to feature k, moment-matched to
   a Gaussian in information form, each row weighted by its probability given that k
   exists. Its content is s's GNSS fix of this step through the row, y = z + g with
   covariance W + R (where the fix observes every V2F component; else s's belief). The
   paper's message carries φ_s, which holds k's own earlier messages and s's earlier
   fixes: sent every step, that information compounds through the loop in time and a
   feature freezes on its first estimate. The fix is new information at every step,
   so a feature's belief is a consistent fusion of independent fixes
   (`feature_messages="fixes"`, the default). With `feature_messages="tracks"` the
   message is s's GNSS track through the row instead (y = z + H x̂_s, cov W + H P_s Hᵀ;
   the track holds no feature information and is independent of the other vehicles'),
   and since one track at two steps holds the same earlier fixes, each vehicle's latest
   message *replaces* its previous one: a feature's belief is its birth prior times one
   message per vehicle that has seen it, each read at this step through the feature
   motion (`rsu_bp.map_messages`). Measured worse on every sumo-* preset: the CV tracks
   are over-confident against SUMO's motion, and where they are consistent the better
   map's errors are correlated between the features one vehicle saw, which the product
   over features treats as independent (docs/rsu_bp.md, "Track messages").
6. **Messages to the vehicles** (Fröhle (23)): μ_{k,s}(x) = (1 − r⁻ P_D p_{k,s}) +
   r⁻ P_D Σ_m ν_{m→k} N(z_m; H f̃ − H x, W + H P̃ Hᵀ), with (f̃, P̃) the feature's belief
   without everything s ever sent it (extrinsic, Fröhle (22); `VehicleMessages`; with
   track messages, the sum without s's stored message, exact; a feature that holds no
   information on its position without it sends s no message). The
   vehicle's belief b_s = φ_s χ_s Π_k μ_{k,s} (26) is not carried into its track:
   next step's messages carry the features' information again (a vehicle without rows
   reports its last belief predicted and updated with GNSS: `RsuBP._step_unknown`).
7. **Existence** of legacy features and **births**: every row that no legacy feature
   explains starts a potential feature with r = P(not legacy) λ_b/κ, its state from the
   row and the vehicle's fix. Births of one step from different vehicles within the
   gate of each other (judged on the vehicles' beliefs) are one feature — an
   approximation of Meyer's sequential processing of sensors, in which the second
   vehicle would see the first one's new feature as legacy. Features with
   r < `prune_threshold` are dropped; those with r ≥ `existence_threshold` are reported.

The feature ids are the filter's own labels (0, 1, …); rows are scored through
``info["v2f_track"]`` (`metrics.track_identities`). Complexity per step: O(P d³) for P
gated pairs (β in closed form), O(P N_p d²) for the messages to the vehicles' particles
(`rsu_bp.vehicles`), plus O(S log F) for the KD-tree queries of S vehicles and F features;
with track messages also O(M d³) for the M stored (feature, vehicle) messages.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cooploc.association import bp_association, gated_pairs, padded_groups, pair_components
from cooploc.estimators.rsu_bp import existence as ex
from cooploc.estimators.rsu_bp.map_messages import TrackMessages
from cooploc.estimators.rsu_bp.vehicles import (
    VehicleMessages,
    group_log_sum,
    log_normal_rows,
)
from cooploc.gaussian import Gaussians, from_information, kf_predict, symmetrize
from cooploc.types import Batch, FloatArray, IntArray, Setup, StateSet, lookup_ids

__all__ = ["FeatureTracker"]

#: a (vehicle, feature) pair whose rows' weights q sum to less than this sends no new
#: track message at the step (its previous one stays): a numerical floor, J = Σ q C⁻¹ ≈ 0
MIN_ROW_WEIGHT = 1e-9

@dataclass
class _Features:
    """Potential features: ids (F,), Gaussian beliefs, existence probabilities (F,)."""

    ids: IntArray
    mean: FloatArray
    cov: FloatArray
    existence: FloatArray

    def keep(self, mask: np.ndarray) -> None:
        self.ids, self.mean = self.ids[mask], self.mean[mask]
        self.cov, self.existence = self.cov[mask], self.existence[mask]


class FeatureTracker:
    """Potential features with existence for `rsu-bp` (see the module docstring)."""

    def __init__(self, setup: Setup, params: Any, clutter_intensity: float) -> None:
        self.setup, self.params = setup, params
        self.v2f = setup.sensors["v2f"]
        self.gnss = setup.sensors.get("gnss")
        dx, df = setup.vehicle_layout.dim, setup.feature_layout.dim
        self.dx, self.df = dx, df
        self.Hx, self.Hf = self.v2f.observation_matrix(dx), self.v2f.observation_matrix(df)
        self.F = setup.feature_motion.transition_matrix(setup.dt)
        self.range = float(getattr(self.v2f, "max_range", np.inf))
        self.p_d = min(float(setup.detection_probability), params.max_detection_probability)
        self.clutter = float(clutter_intensity)
        indices = list(self.v2f.state_indices)
        position = set(setup.feature_layout.position)
        self.z_pos = np.array([j for j, i in enumerate(indices) if i in position], dtype=np.int64)
        self.z_rest = np.array([j for j, i in enumerate(indices) if i not in position], dtype=np.int64)
        self.xy = self.z_pos[:2]
        from scipy.stats import chi2
        self.gate = float(chi2.ppf(params.gate_probability, len(indices)))
        # birth prior information of the feature state: none on positions (uniform birth
        # intensity), N(0, σ_b²) on the other components
        birth_var = np.full(df, np.inf)
        rest_state = [i for i in range(df) if i not in position]
        birth_var[rest_state] = params.birth_velocity_std**2
        self.birth_info = np.diag(1.0 / birth_var)
        # the GNSS fix replaces the vehicle belief if it observes every V2F component
        self.fix_map: IntArray | None = None
        if self.gnss is not None:
            g_idx = list(self.gnss.state_indices)
            if all(i in g_idx for i in indices):
                self.fix_map = np.array([g_idx.index(i) for i in indices], dtype=np.int64)
        self.features = _Features(np.zeros(0, np.int64), np.zeros((0, df)), np.zeros((0, df, df)),
                                  np.zeros(0))
        self.next_id = 0
        # (vehicle id, feature id) → the information (Λ, η) the vehicle has sent the feature
        self.sent: dict[tuple[int, int], tuple[FloatArray, FloatArray]] = {}
        self.now = 0                                    # steps since the first frame
        # feature_messages="tracks": each vehicle's latest track-based message per feature
        self.store: TrackMessages | None = None
        if params.feature_messages == "tracks":
            self.store = TrackMessages(self.Hf, self.F, self._step_noise())

    def _step_noise(self) -> FloatArray:
        """Q (df, df) of one step of the feature motion for the track messages' ages: the
        model's own, or for a Q turned with the heading its average over four headings."""
        motion, dt = self.setup.feature_motion, self.setup.dt
        if not motion.state_dependent_noise:
            return np.asarray(motion.noise_covariance(dt)).reshape(self.df, self.df)
        states = np.zeros((4, self.df))
        velocity = self.setup.feature_layout.velocity or self.setup.feature_layout.position
        angles = np.pi / 4 * np.arange(4)
        states[:, velocity[0]], states[:, velocity[1]] = np.cos(angles), np.sin(angles)
        return np.asarray(motion.noise_covariance(dt, states)).mean(axis=0)

    # ------------------------------------------------------------------ step

    def predict(self, steps: int | None) -> None:
        self.now += steps or 0
        f = self.features
        if not f.ids.size or not steps:
            return
        if self.store is not None:
            self._recombine(f.ids, prune=True)
        else:
            motion, dt = self.setup.feature_motion, self.setup.dt
            belief = Gaussians(f.mean, f.cov)
            for _ in range(steps):
                belief = kf_predict(belief, self.F, motion.noise_covariance(dt, belief.mean))
            f.mean, f.cov = belief.mean, belief.cov
        f.existence = f.existence * self.params.survival_probability**steps

    def update(self, vehicle_ids: IntArray, v_mean: FloatArray, v_cov: FloatArray, v2f: Batch,
               gnss: Batch | None) -> tuple[VehicleMessages, IntArray, dict[str, Any]]:
        """Steps 2–7 for the V2F rows `v2f` of present vehicles.

        Parameters
        ----------
        vehicle_ids (S,), v_mean, v_cov : the vehicles and their beliefs φχ (Gaussian).

        Returns
        -------
        The messages μ_{k,s} to the vehicles, the track id of every row (−1: none), diagnostics.
        """
        prm, f, p_d = self.params, self.features, self.p_d
        S = v_mean.shape[0]
        R = len(v2f)
        s_row = lookup_ids(vehicle_ids, v2f.sensor)[0]
        Hx, Hf = self.Hx, self.Hf
        c_mean = v_mean @ Hx.T                                                   # H x̄_s
        c_cov = Hx @ v_cov @ Hx.T
        # 2.–3. gated pairs and their log β (P,)
        r_idx, k_idx, log_beta = self._gate(v2f, s_row, c_mean, c_cov)
        # pairs (s, k) with a gated row, rows sorted by pair
        sk_key = s_row[r_idx] * max(f.ids.size, 1) + k_idx
        order = np.lexsort((r_idx, sk_key))
        r_idx, k_idx, sk_key, log_beta = r_idx[order], k_idx[order], sk_key[order], log_beta[order]
        sk_unique, pair = np.unique(sk_key, return_inverse=True)
        n_sk = sk_unique.size
        sk_s = sk_unique // max(f.ids.size, 1)
        sk_k = sk_unique % max(f.ids.size, 1)
        p_in_sk = self._p_visible(sk_s, sk_k, v_mean, v_cov)
        r_minus = f.existence
        # 4. association per vehicle with rows, padded (V, K_max, M_max)
        log_birth = self._log_birth(v2f, s_row, v_mean, v_cov)
        log_kappa = ex.row_weights(self.clutter, log_birth)
        v_of_row = s_row
        m_index, m_mask = padded_groups(v_of_row, S)
        m_slot = np.empty(R, dtype=np.int64)
        m_slot[m_index[m_mask]] = np.nonzero(m_mask)[1]
        k_index, k_mask = padded_groups(sk_s, S)
        k_slot = np.empty(n_sk, dtype=np.int64)
        k_slot[k_index[k_mask]] = np.nonzero(k_mask)[1]
        Kmax = max(k_mask.shape[1], 1)
        log_psi = np.full((S, Kmax, m_mask.shape[1]), -np.inf)
        log_missed = np.full((S, Kmax), -np.inf)
        log_psi[s_row[r_idx], k_slot[pair], m_slot[r_idx]] = ex.legacy_weights(
            log_beta[:, None], r_minus[k_idx], p_d, p_in_sk[pair])[0][:, 0]
        log_missed[sk_s, k_slot] = ex.legacy_weights(
            np.zeros((n_sk, 0)), r_minus[sk_k], p_d, p_in_sk)[1]
        fmask = np.zeros((S, Kmax), bool)
        fmask[sk_s, k_slot] = True
        kappa = np.where(m_mask, log_kappa[np.where(m_mask, m_index, 0)], -np.inf)
        marg = bp_association(log_psi, log_missed, kappa, prm.n_da_iterations,
                              feature_mask=fmask, measurement_mask=m_mask)
        log_nu = marg.log_nu[s_row[r_idx], k_slot[pair], m_slot[r_idx]]          # (P,)
        not_legacy = marg.clutter[s_row, m_slot]                                   # (R,)
        # existence likelihood L_{k,s} per pair with rows, then misses of features in range
        log_nb = group_log_sum(log_nu + log_beta, pair, n_sk)
        log_L = ex.log_existence_likelihood(log_nb, p_d, p_in_sk)                  # (n_sk,)
        log_L_feature = np.zeros(f.ids.size)
        np.add.at(log_L_feature, sk_k, log_L)
        _, miss_k, miss_p = self._in_range(v_mean, v_cov, sk_unique)
        np.add.at(log_L_feature, miss_k,
                  ex.log_existence_likelihood(np.full(miss_k.size, -np.inf), p_d, miss_p))
        # 5. feature update, information form: per row, weight P(row | k exists, s)
        q = np.exp(np.log(p_d) + log_nu + log_beta - log_L[pair])
        with np.errstate(divide="ignore"):
            log_coef = np.log(r_minus[k_idx] * p_d) + log_nu
            log_miss = np.log1p(-r_minus[sk_k] * p_d * p_in_sk)
        if self.store is None:
            lam, eta, touched, ext_mean, ext_cov = self._fix_messages(
                v2f, r_idx, s_row, v_mean, v_cov, gnss, q, pair, n_sk, sk_s, sk_k, vehicle_ids)
            proper = np.ones(n_sk, dtype=bool)
        else:
            ext_mean, ext_cov, proper = self._track_messages(
                v2f, r_idx, s_row, v_mean, v_cov, q, pair, n_sk, sk_s, sk_k, vehicle_ids)
        # 6. messages to vehicles from the extrinsic beliefs (without what s sent k); a
        # feature that knows nothing of its position without s sends s no message
        sent = proper[pair]
        messages = VehicleMessages(
            S, Hx, s_row[r_idx][sent], pair[sent], sk_s,
            v2f.z[r_idx][sent] - ext_mean[pair][sent] @ Hf.T,
            v2f.cov[r_idx][sent] + Hf @ ext_cov[pair][sent] @ Hf.T, log_coef[sent], log_miss)
        # posterior features (with the fixes; the tracks' were recombined above); 7. existence
        if self.store is None:
            post = from_information(lam, eta)
            f.mean[touched], f.cov[touched] = post.mean, post.cov
        f.existence = ex.legacy_existence(r_minus, log_L_feature)
        # the decided track of every row: its MAP legacy feature, else the feature it starts
        track = np.full(R, -1, dtype=np.int64)
        meas = marg.measurement[s_row, m_slot]                                      # (R, Kmax)
        best = meas.argmax(axis=1) if meas.shape[1] else np.zeros(R, np.int64)
        best_p = meas.max(axis=1, initial=0.0)
        legacy_row = (best_p >= prm.association_threshold) & (best_p > not_legacy)
        slot_feature = np.full((S, Kmax), -1, dtype=np.int64)
        slot_feature[sk_s, k_slot] = f.ids[sk_k]
        track[legacy_row] = slot_feature[s_row[legacy_row], best[legacy_row]]
        r_new = ex.new_existence(not_legacy, log_birth, log_kappa)
        n_born = self._births(v2f, s_row, vehicle_ids, messages.gaussian(v_mean, v_cov), r_new, track, gnss,
                              own=Gaussians(v_mean, v_cov))
        self._prune()
        info = {"potential_features": int(f.ids.size), "features_born": n_born,
                "gated_pairs": int(r_idx.size), "da_iterations": marg.iterations}
        return messages, track, info

    def estimate(self) -> tuple[StateSet, FloatArray]:
        """Reported features (r ≥ existence_threshold) and their existence probabilities."""
        f = self.features
        shown = f.existence >= self.params.existence_threshold
        return StateSet(f.ids[shown], f.mean[shown], f.cov[shown]), f.existence[shown]

    # ------------------------------------------------------------ pieces

    def _gate(self, v2f: Batch, s_row: IntArray, c_mean: FloatArray, c_cov: FloatArray
              ) -> tuple[IntArray, IntArray, FloatArray]:
        """(row, feature) pairs whose residual lies inside the gate, and log β of each (step 3).

        β = N(z − (H f̄ − H x̄_s); 0, S), S = W + H P_f Hᵀ + H P_s Hᵀ: the same residual
        and covariance as the gate's distance.
        """
        f = self.features
        if not f.ids.size or not len(v2f):
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        from scipy.spatial import cKDTree
        Hf, xy = self.Hf, self.xy
        f_pos = (f.mean @ Hf.T)[:, xy]
        f_var = np.trace((Hf @ f.cov @ Hf.T)[:, xy][:, :, xy], axis1=1, axis2=2)
        row_pos = (c_mean[s_row] + v2f.z)[:, xy]
        row_var = (np.trace(c_cov[s_row][:, xy][:, :, xy], axis1=1, axis2=2)
                   + np.trace(v2f.cov[:, xy][:, :, xy], axis1=1, axis2=2))
        radius = np.sqrt(self.gate * (row_var + f_var.max()))
        hits = cKDTree(f_pos).query_ball_point(row_pos, radius)
        counts = np.fromiter((len(h) for h in hits), dtype=np.int64, count=len(hits))
        r_idx = np.repeat(np.arange(len(v2f)), counts)
        k_idx = np.fromiter((k for h in hits for k in h), dtype=np.int64, count=int(counts.sum()))
        if not r_idx.size:
            return r_idx, k_idx, np.zeros(0)
        resid = v2f.z[r_idx] - (f.mean[k_idx] @ Hf.T - c_mean[s_row[r_idx]])
        S = v2f.cov[r_idx] + Hf @ f.cov[k_idx] @ Hf.T + c_cov[s_row[r_idx]]
        L = np.linalg.cholesky(S)
        white = np.linalg.solve(L, resid[..., None])[..., 0]                      # L⁻¹ r
        d2 = np.einsum("pi,pi->p", white, white)
        inside = d2 <= self.gate
        log_det = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        log_beta = -0.5 * (resid.shape[1] * np.log(2.0 * np.pi) + log_det + d2)
        return r_idx[inside], k_idx[inside], log_beta[inside]

    def _p_visible(self, s: IntArray, k: IntArray, v_mean: FloatArray, v_cov: FloatArray) -> FloatArray:
        """P(feature k within the sensing range of vehicle s), Gaussian in the distance."""
        if not np.isfinite(self.range):
            return np.ones(s.size)
        from scipy.special import ndtr
        f, Hf, Hx, xy = self.features, self.Hf, self.Hx, self.xy
        fp = (f.mean[k] @ Hf.T)[:, xy]
        vp = (v_mean[s] @ Hx.T)[:, xy]
        var = (np.trace((Hf @ f.cov[k] @ Hf.T)[:, xy][:, :, xy], axis1=1, axis2=2)
               + np.trace((Hx @ v_cov[s] @ Hx.T)[:, xy][:, :, xy], axis1=1, axis2=2)) / 2.0
        d = np.hypot(*(fp - vp).T)
        return ndtr((self.range - d) / np.sqrt(var + 1e-12))

    def _in_range(self, v_mean: FloatArray, v_cov: FloatArray, with_rows: IntArray
                  ) -> tuple[IntArray, IntArray, FloatArray]:
        """(s, k, P(in range)) of features near a vehicle that none of its rows gated with."""
        f = self.features
        S, F = v_mean.shape[0], f.ids.size
        if not F or not S:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        if np.isfinite(self.range):
            from scipy.spatial import cKDTree
            xy = self.xy
            vp = (v_mean @ self.Hx.T)[:, xy]
            sd = np.sqrt(np.trace((self.Hx @ v_cov @ self.Hx.T)[:, xy][:, :, xy], axis1=1, axis2=2))
            hits = cKDTree((f.mean @ self.Hf.T)[:, xy]).query_ball_point(vp, self.range + 3.0 * sd)
            counts = np.fromiter((len(h) for h in hits), dtype=np.int64, count=S)
            s = np.repeat(np.arange(S), counts)
            k = np.fromiter((j for h in hits for j in h), dtype=np.int64, count=int(counts.sum()))
        else:
            s, k = np.repeat(np.arange(S), F), np.tile(np.arange(F), S)
        fresh = ~np.isin(s * max(F, 1) + k, with_rows)
        s, k = s[fresh], k[fresh]
        return s, k, self._p_visible(s, k, v_mean, v_cov)

    def _log_birth(self, v2f: Batch, s_row: IntArray, v_mean: FloatArray, v_cov: FloatArray
                   ) -> FloatArray:
        """log λ_b(z_m) = log μ_b P_D + log N(z_rest + H x̄_rest; 0, σ_b² + W + H P Hᵀ) per row."""
        base = np.log(self.params.birth_density * self.p_d) * np.ones(len(v2f))
        rest = self.z_rest
        if not rest.size or not len(v2f):
            return base
        c = (v_mean @ self.Hx.T)[:, rest][s_row]
        C = ((self.Hx @ v_cov @ self.Hx.T)[:, rest][:, :, rest][s_row]
             + v2f.cov[:, rest][:, :, rest] + self.params.birth_velocity_std**2 * np.eye(rest.size))
        return base + log_normal_rows((v2f.z[:, rest] + c)[:, None, :], C)[:, 0]

    def _sources(self, v2f: Batch, rows: IntArray, s_row: IntArray, v_mean: FloatArray,
                 v_cov: FloatArray, gnss: Batch | None) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Pseudo-measurements y = H f + noise (P, dz), covariances, and which exist (step 5)."""
        s = s_row[rows]
        y = v2f.z[rows] + v_mean[s] @ self.Hx.T
        C = v2f.cov[rows] + self.Hx @ v_cov[s] @ self.Hx.T
        use = np.zeros(rows.size, dtype=bool)
        if self.fix_map is not None and gnss is not None and len(gnss):
            g_row, use = lookup_ids(gnss.subject, v2f.sensor[rows])
            m, g = self.fix_map, g_row[use]
            y[use] = v2f.z[rows[use]] + gnss.z[g][:, m]
            C[use] = v2f.cov[rows[use]] + gnss.cov[g][:, m][:, :, m]
        return y, C, use

    def _fix_messages(self, v2f: Batch, r_idx: IntArray, s_row: IntArray, v_mean: FloatArray,
                      v_cov: FloatArray, gnss: Batch | None, q: FloatArray, pair: IntArray, n_sk: int,
                      sk_s: IntArray, sk_k: IntArray, vehicle_ids: IntArray
                      ) -> tuple[FloatArray, FloatArray, IntArray, FloatArray, FloatArray]:
        """Step 5 with the fixes (`feature_messages="fixes"`): the posterior information
        (Λ, η) of the features `touched`, and the extrinsic beliefs per (s, k) pair."""
        f, Hf = self.features, self.Hf
        y, C, usable = self._sources(v2f, r_idx, s_row, v_mean, v_cov, gnss)
        q = np.where(usable, q, 0.0)
        Cinv = np.linalg.inv(C)
        info_m = np.einsum("ji,pjk,kl->pil", Hf, Cinv, Hf) * q[:, None, None]       # Hᵀ C⁻¹ H q
        info_v = np.einsum("ji,pjk,pk->pi", Hf, Cinv, y) * q[:, None]
        own_m = np.zeros((n_sk, self.df, self.df))
        own_v = np.zeros((n_sk, self.df))
        np.add.at(own_m, pair, info_m)
        np.add.at(own_v, pair, info_v)
        touched = np.unique(sk_k)
        lam_prior = np.linalg.inv(f.cov[touched])
        eta_prior = np.einsum("fij,fj->fi", lam_prior, f.mean[touched])
        where = np.searchsorted(touched, sk_k)
        lam = lam_prior.copy()
        eta = eta_prior.copy()
        np.add.at(lam, where, own_m)
        np.add.at(eta, where, own_v)
        # the extrinsic beliefs: without what s ever sent k
        keys = list(zip(vehicle_ids[sk_s].tolist(), f.ids[sk_k].tolist(), strict=True))
        zero = (np.zeros((self.df, self.df)), np.zeros(self.df))
        past = [self.sent.get(key, zero) for key in keys]
        sent_m = own_m + np.array([m for m, _ in past]).reshape(own_m.shape)
        sent_v = own_v + np.array([v for _, v in past]).reshape(own_v.shape)
        self.sent.update(zip(keys, zip(sent_m, sent_v, strict=True), strict=True))
        extrinsic = self._without(lam[where], eta[where], sent_m, sent_v)
        return lam, eta, touched, extrinsic.mean, extrinsic.cov

    def _track_messages(self, v2f: Batch, r_idx: IntArray, s_row: IntArray, v_mean: FloatArray,
                        v_cov: FloatArray, q: FloatArray, pair: IntArray, n_sk: int, sk_s: IntArray,
                        sk_k: IntArray, vehicle_ids: IntArray) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Step 5 with the tracks (`feature_messages="tracks"`, `rsu_bp.map_messages`).

        Vehicle s's message to k, y = z + H x̂_s with covariance C = W + H P_s Hᵀ from its
        GNSS track, J = Σ_m q_m C_m⁻¹, j = Σ_m q_m C_m⁻¹ y_m over its rows of k, replaces
        s's previous message to k, and the touched features are recombined from their
        messages.

        Returns the extrinsic beliefs per (s, k) pair after the update (the sum without
        s's message: exact) and which are proper (hold information on every component).
        """
        f, store = self.features, self.store
        touched = np.unique(sk_k)
        where = np.searchsorted(touched, sk_k)
        y, C, _ = self._sources(v2f, r_idx, s_row, v_mean, v_cov, None)
        Cinv = np.linalg.inv(C)
        J = np.zeros((n_sk, *Cinv.shape[1:]))
        j = np.zeros((n_sk, y.shape[1]))
        np.add.at(J, pair, Cinv * q[:, None, None])
        np.add.at(j, pair, np.einsum("pij,pj->pi", Cinv, y) * q[:, None])
        # a pair whose rows all have (numerically) no weight sends nothing new
        new = np.bincount(pair, weights=q, minlength=n_sk) > MIN_ROW_WEIGHT
        store.replace(f.ids[sk_k[new]], vehicle_ids[sk_s[new]], self.now, J[new], j[new])
        lam, eta = self._recombine(f.ids[touched], prune=False)
        return self._extrinsic(lam, eta, where, sk_s, sk_k, vehicle_ids)

    def _extrinsic(self, lam: FloatArray, eta: FloatArray, where: IntArray, sk_s: IntArray,
                   sk_k: IntArray, vehicle_ids: IntArray) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Per (s, k) pair, k's belief (information `lam`, `eta` at `where`) without s's
        stored message, exactly; and which of these hold information on every component
        (the others get placeholder moments and send no message)."""
        f, store = self.features, self.store
        ext_m, ext_v = lam[where].copy(), eta[where].copy()
        mine = store.find(f.ids[sk_k], vehicle_ids[sk_s])
        has = mine >= 0
        own_m, own_v = store.read(self.now, mine[has])
        ext_m[has] -= own_m
        ext_v[has] -= own_v
        ext_m = symmetrize(ext_m)
        scale = np.trace(lam[where], axis1=1, axis2=2)
        proper = np.linalg.eigvalsh(ext_m)[:, 0] > 1e-9 * scale
        mean, cov = np.zeros((where.size, self.df)), np.broadcast_to(np.eye(self.df), ext_m.shape).copy()
        if proper.any():
            ext = from_information(ext_m[proper], ext_v[proper])
            mean[proper], cov[proper] = ext.mean, ext.cov
        return mean, cov, proper

    def _recombine(self, ids: IntArray, prune: bool) -> tuple[FloatArray, FloatArray]:
        """The beliefs of the features `ids` (sorted) from their stored messages read at
        this step (`TrackMessages.beliefs`), written into `features`; their (Λ, η)."""
        f, store = self.features, self.store
        lam, eta, index, where, lam_m = store.beliefs(self.now, ids, self.birth_info)
        post = from_information(lam, eta)
        at = np.searchsorted(f.ids, ids)
        f.mean[at], f.cov[at] = post.mean, post.cov
        if prune:
            store.prune(index, lam_m, np.trace(lam, axis1=1, axis2=2)[where])
        return lam, eta

    def _without(self, lam: FloatArray, eta: FloatArray, sent_m: FloatArray, sent_v: FloatArray
                 ) -> Gaussians:
        """The feature beliefs without the information a vehicle sent them.

        Exact for a static feature; the feature's process noise since makes the stored
        information an overestimate, so where the difference is not positive definite
        the stored part is scaled down until it is.
        """
        out_m, out_v = symmetrize(lam - sent_m), eta - sent_v
        for shrink in (0.5, 0.0):
            bad = np.linalg.eigvalsh(out_m)[:, 0] <= 1e-9 * np.trace(lam, axis1=1, axis2=2)
            if not bad.any():
                break
            out_m[bad] = symmetrize(lam[bad] - shrink * sent_m[bad])
            out_v[bad] = eta[bad] - shrink * sent_v[bad]
        return from_information(out_m, out_v)

    def _births(self, v2f: Batch, s_row: IntArray, vehicle_ids: IntArray, belief: Gaussians,
                r_new: FloatArray, track: IntArray, gnss: Batch | None, own: Gaussians | None = None
                ) -> int:
        """New potential features from rows no legacy feature explains (step 7).

        Grouped on the vehicles' beliefs `belief`; the state from the fixes (or, with
        `feature_messages="tracks"`, from the GNSS tracks `own`, stored as each vehicle's
        first message to the feature)."""
        prm = self.params
        rows = np.flatnonzero((r_new >= prm.prune_threshold) & (track < 0))
        if not rows.size:
            return 0
        s = s_row[rows]
        mean, cov = belief.mean, belief.cov
        Hf = self.Hf
        if self.store is None:
            y, C, _ = self._sources(v2f, rows, s_row, mean, cov, gnss)
        else:
            y, C, _ = self._sources(v2f, rows, s_row, own.mean, own.cov, None)
        Cinv = np.linalg.inv(C)
        lam = np.einsum("ji,pjk,kl->pil", Hf, Cinv, Hf)
        eta = np.einsum("ji,pjk,pk->pi", Hf, Cinv, y)
        # one feature or two: judged on the vehicles' beliefs (the fixes are too coarse)
        group = self._same_feature(v2f.z[rows] + mean[s] @ self.Hx.T,
                                   v2f.cov[rows] + self.Hx @ cov[s] @ self.Hx.T, s)
        n = int(group.max()) + 1
        lam_g = np.repeat(self.birth_info[None], n, axis=0)
        eta_g = np.zeros((n, self.df))
        np.add.at(lam_g, group, lam)
        np.add.at(eta_g, group, eta)
        log_absent = np.zeros(n)
        np.add.at(log_absent, group, np.log1p(-np.minimum(r_new[rows], 1.0 - 1e-12)))
        born = from_information(lam_g, eta_g)
        ids = self.next_id + np.arange(n, dtype=np.int64)
        self.next_id += n
        f = self.features
        f.ids = np.concatenate([f.ids, ids])
        f.mean = np.concatenate([f.mean, born.mean])
        f.cov = np.concatenate([f.cov, born.cov])
        f.existence = np.concatenate([f.existence, -np.expm1(log_absent)])
        track[rows] = ids[group]
        if self.store is None:
            self.sent.update(zip(zip(vehicle_ids[s].tolist(), ids[group].tolist(), strict=True),
                                 zip(lam, eta, strict=True), strict=True))
        else:
            self.store.replace(ids[group], vehicle_ids[s], self.now, Cinv,
                               np.einsum("pij,pj->pi", Cinv, y))
        return n

    def _same_feature(self, y: FloatArray, C: FloatArray, s: IntArray) -> IntArray:
        """Group births of one step: rows of different vehicles inside each other's gate."""
        a, b, _ = gated_pairs(y, C, s, self.gate, tuple(self.xy), inclusive=True)
        return pair_components(y.shape[0], a, b)

    def _prune(self) -> None:
        f = self.features
        keep = f.existence >= self.params.prune_threshold
        if not keep.all():
            gone = set(f.ids[~keep].tolist())
            if self.store is not None:
                self.store.drop_features(f.ids[~keep])
            f.keep(keep)
            self.sent = {p: v for p, v in self.sent.items() if p[1] not in gone}
