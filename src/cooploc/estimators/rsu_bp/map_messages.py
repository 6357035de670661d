"""The latest track-based message of every vehicle to every feature it has seen (`rsu-bp`, cities).

With `feature_messages="tracks"` (`rsu_bp.tracking` step 5) vehicle s's message to
feature k is its GNSS track φ_s (a `gnss-kf` filter, which holds no feature information)
carried through its rows of k: y = z + H x̂_s, covariance C = W + H P_s Hᵀ, rows weighted
by q = P(row from k | k exists) as in the information-form moment match of Fröhle (21):
J = Σ_m q_m C_m⁻¹, j = Σ_m q_m C_m⁻¹ y_m, information on H f at the message's step.

Two tracks are independent (each vehicle's own GNSS), but one track at two steps is not
(the same earlier fixes, integrated by the motion model). So a feature's belief takes,
per vehicle, only its *latest* message, and a new one replaces the previous one instead
of adding to it: the bookkeeping of decentralised data fusion, where the information a
node already sent is removed before its new estimate is fused (the channel filter;
Grime & Durrant-Whyte, "Data fusion in decentralized sensor networks", Control Eng.
Practice 2(5), 1994). In the BP of Meyer et al. ("Message passing algorithms for
scalable multitarget tracking", Proc. IEEE 2018) and BP-SLAM (Leitinger et al., "A
belief propagation algorithm for multipath-based SLAM", IEEE Trans. Wireless Commun.
2019) the agent's message to a map feature comes from its belief *with* the map, and the
new messages multiply the feature's predicted belief at every step: the loop in time
that this replaces (there it is an accepted approximation; with GNSS tracks metres wide
and many steps per feature it froze the features here, `rsu_bp.tracking` step 5).

A message of step t is information on f(t); the belief is at step k = t + n. Under the
feature motion f(k) = Fⁿ f(t) + Σ noise, f(t) = F⁻ⁿ f(k) − Σ_{j=1..n} F⁻ʲ w, so the
message read at step k is y = H F⁻ⁿ f(k) + e with covariance J⁻¹ + H Q_b(n) Hᵀ,
Q_b(n) = Σ_{j=1..n} F⁻ʲ Q F⁻ʲᵀ: positive definite at any age, nothing to subtract.
The feature's belief is its birth prior times these messages,

    Λ = Λ_b + Σ_s A_nᵀ S_s⁻¹ A_n,  η = Σ_s A_nᵀ S_s⁻¹ y_s,  A_n = H F⁻ⁿ, S_s = J_s⁻¹ + H Q_b(n) Hᵀ,

and the extrinsic belief for vehicle s (Fröhle (22)) is the same sum without s's term —
exact, no shrinking. Approximations: (i) the process noise between two messages' steps
is counted once per message, as if independent (exact with Q = 0; over-confident for a
walking pedestrian seen by several vehicles at about the same time; the sumo scenes give
every feature, poles too, the pedestrians' Q, so a pole's old messages are discounted
although it stands still); (ii) a state-dependent Q (turned with the heading) is
replaced by its average over four headings; (iii) the birth prior Λ_b (velocity only) is
read at the current step; (iv) a vehicle's earlier rows of k leave with its earlier
message, their V2F noise (decimetres) being far below the track's (metres), and the
track errors of one vehicle in the several features it saw at one step are correlated,
which the product over features in the vehicles' beliefs ignores (measured in
docs/rsu_bp.md, "Track messages": worse than the fixes on every sumo-* preset).

Messages whose information is below `NEGLIGIBLE` of their feature's are dropped (an old
message of a moving feature). Cost per step: O(M dz³) for M stored messages, vectorised.
"""

from __future__ import annotations

import numpy as np

from cooploc.types import FloatArray, IntArray, lookup_ids

__all__ = ["NEGLIGIBLE", "TrackMessages"]

#: a message with less than this share of its feature's information (trace) is dropped
NEGLIGIBLE = 1e-6


class TrackMessages:
    """Per (feature, vehicle) the latest message (J, j) on H f at its step (see module docstring).

    Parameters
    ----------
    H : (dz, df) what the rows observe of the feature state.
    F : (df, df) the feature transition of one step; Q : (df, df) its process noise.
    """

    def __init__(self, H: FloatArray, F: FloatArray, Q: FloatArray) -> None:
        self.H, self.F_inv, self.Q = H, np.linalg.inv(F), Q
        dz, df = H.shape
        self.A = H[None].copy()                      # (n+1, dz, df): H F⁻ⁿ
        self.B = np.zeros((1, dz, dz))               # (n+1, dz, dz): H Q_b(n) Hᵀ
        self._Finv_n, self._Qb_n = np.eye(df), np.zeros((df, df))
        self.feature = np.zeros(0, np.int64)
        self.vehicle = np.zeros(0, np.int64)
        self.step = np.zeros(0, np.int64)
        self.info = np.zeros((0, dz, dz))
        self.vec = np.zeros((0, dz))

    def __len__(self) -> int:
        return int(self.feature.size)

    def _key(self, feature: IntArray, vehicle: IntArray) -> IntArray:
        return (np.asarray(feature, np.int64) << 32) | np.asarray(vehicle, np.int64)

    def replace(self, feature: IntArray, vehicle: IntArray, step: int, info: FloatArray,
                vec: FloatArray) -> None:
        """Store the messages (J (P, dz, dz), j (P, dz)) of this step, replacing each
        (feature, vehicle)'s previous one; several of one pair in the batch are summed."""
        if not feature.size:
            return
        key = self._key(feature, vehicle)
        uniq, inv = np.unique(key, return_inverse=True)
        J = np.zeros((uniq.size, *info.shape[1:]))
        j = np.zeros((uniq.size, vec.shape[1]))
        np.add.at(J, inv, info)
        np.add.at(j, inv, vec)
        keep = ~np.isin(self._key(self.feature, self.vehicle), uniq)
        self.feature = np.concatenate([self.feature[keep], uniq >> 32])
        self.vehicle = np.concatenate([self.vehicle[keep], uniq & 0xFFFFFFFF])
        self.step = np.concatenate([self.step[keep], np.full(uniq.size, step, np.int64)])
        self.info = np.concatenate([self.info[keep], J])
        self.vec = np.concatenate([self.vec[keep], j])

    def find(self, feature: IntArray, vehicle: IntArray) -> IntArray:
        """Index of each (feature, vehicle)'s message, −1 where it has none."""
        pos, found = lookup_ids(self._key(self.feature, self.vehicle), self._key(feature, vehicle))
        return np.where(found, pos, -1)

    def drop_features(self, gone: IntArray) -> None:
        self._keep(~np.isin(self.feature, gone))

    def _keep(self, mask: np.ndarray) -> None:
        self.feature, self.vehicle, self.step = self.feature[mask], self.vehicle[mask], self.step[mask]
        self.info, self.vec = self.info[mask], self.vec[mask]

    def _tables(self, n_max: int) -> None:
        """Extend A_n = H F⁻ⁿ and B_n = H Q_b(n) Hᵀ to n_max."""
        have = self.A.shape[0] - 1
        if n_max <= have:
            return
        H, A, B = self.H, [], []
        for _ in range(have, n_max):
            self._Finv_n = self._Finv_n @ self.F_inv
            self._Qb_n = self._Qb_n + self._Finv_n @ self.Q @ self._Finv_n.T
            A.append(H @ self._Finv_n)
            B.append(H @ self._Qb_n @ H.T)
        self.A = np.concatenate([self.A, np.array(A)])
        self.B = np.concatenate([self.B, 0.5 * (np.array(B) + np.swapaxes(np.array(B), 1, 2))])

    def read(self, now: int, index: IntArray) -> tuple[FloatArray, FloatArray]:
        """Messages `index` read at step `now`: information (Λ_m (P, df, df), η_m (P, df))."""
        n = now - self.step[index]
        self._tables(int(n.max(initial=0)))
        A = self.A[n]
        C = np.linalg.inv(self.info[index])                                        # J⁻¹
        y = np.einsum("pij,pj->pi", C, self.vec[index])                             # J⁻¹ j
        S = C + self.B[n]
        SinvA = np.linalg.solve(S, A)                                              # S⁻¹ A
        lam = np.swapaxes(A, 1, 2) @ SinvA
        eta = np.einsum("pji,pj->pi", SinvA, y)
        return 0.5 * (lam + np.swapaxes(lam, 1, 2)), eta

    def beliefs(self, now: int, ids: IntArray, prior_info: FloatArray
                ) -> tuple[FloatArray, FloatArray, IntArray, IntArray, FloatArray]:
        """Information (Λ (F, df, df), η (F, df)) of the features `ids` (sorted) at step
        `now`: `prior_info` plus their messages read at `now`. Also the messages used:
        their index in the store (P,), their feature's position in `ids` (P,), Λ_m."""
        index = np.flatnonzero(np.isin(self.feature, ids))
        lam_m, eta_m = self.read(now, index)
        where = np.searchsorted(ids, self.feature[index])
        lam = np.repeat(prior_info[None], ids.size, axis=0)
        eta = np.zeros((ids.size, prior_info.shape[0]))
        np.add.at(lam, where, lam_m)
        np.add.at(eta, where, eta_m)
        return lam, eta, index, where, lam_m

    def prune(self, index: IntArray, lam_m: FloatArray, feature_trace: FloatArray) -> None:
        """Drop the messages `index` whose information is below `NEGLIGIBLE` of their
        feature's (trace; `feature_trace` (P,) of each message's feature)."""
        small = np.trace(lam_m, axis1=1, axis2=2) < NEGLIGIBLE * feature_trace
        if small.any():
            mask = np.ones(len(self), bool)
            mask[index[small]] = False
            self._keep(mask)
