"""`sme-ukf`: the SME pseudo-measurement under an unscented Kalman filter (Zhang et al. 2016 §4.2.3).

Paper: Zhang, Hinz, Gulati, Clarke & Knoll, GeoInformatica 2016
(``papers/001_80a6c560b7fdaa20.txt``). §4.2.3 says that EKF and UKF "do not give
satisfying results" with polynomials up to order 5; this filter is that check
(`cooploc reproduce zhang2016` reports what we measure).

Model
-----
A Gaussian over the joint state x = [x¹; …; xᴺ] (eq. 1), mean (N, dx) and joint
covariance (N dx, N dx), predicted block by block by the motion model (eqs. 15–16):
m ← A m, P ← A P Aᵀ + Q. The update passes the scaled sigma points (α, β, κ; Wan &
van der Merwe 2000) through the stacked pseudo-measurement of eq. (19)
(`PseudoMeasurement.predict`: E[y | x] with its bias, and R(x) per sigma point,
``docs/sme.md``), with R averaged over the sigma points:

    ȳ = Σ W_m Y,  S = Σ W_c (Y − ȳ)(Y − ȳ)ᵀ + Σ W_m R,  C = Σ W_c (X − m)(Y − ȳ)ᵀ,
    K = C S⁻¹,  m ← m + K (y − ȳ),  P ← P − K S Kᵀ.

``info["nis"]``: the NIS (y − ȳ)ᵀ S⁻¹ (y − ȳ) of the update with its dim y degrees of
freedom ((0.0, 0) on a step without pseudo-measurement; `types.Estimate`) — with S from
the unscented transform of a nonlinear map it is χ² only approximately.

Choice the paper leaves open: when the update loses positive definiteness, the spectrum
is lifted to 1e-9 (``info["covariance_repaired"]``). Where the joint covariance has no
Cholesky factor for the sigma points, or S is singular (the sums of powers lose all
precision when the belief is far from the rows), the filter raises `EstimatorError`
saying which.

In traffic (per-radar mode, `filter_base`) the same unscented update is applied per
group (`_update_group`): a radar's eq. (18) over the vehicles it sees, or a gate group's
eq. (17), on the group's independent Gaussian blocks. A singular innovation covariance
there skips that group instead of failing the run: a radar with the reason in
``info["radar_skipped"]``, a GPS group counted in ``info["gnss_groups_skipped"]``.

Complexity per step: O((dx N)³) for the joint covariance and O(dx N · N⁴) for the
complex moments at the 2 dx N + 1 sigma points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from cooploc.errors import EstimatorError
from cooploc.estimators.sme.filter_base import _SmeFilter, _SmeParams
from cooploc.estimators.sme.pseudo_measurement import PseudoMeasurement
from cooploc.gaussian import block_diagonal, nis, symmetrize
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.types import Estimate, FloatArray, Frame, Setup, StateSet

__all__ = ["SmeUKF", "SmeUKFParams"]


@dataclass(frozen=True)
class SmeUKFParams(_SmeParams):
    """`sme-ukf` parameters: the scaled unscented transform (Wan & van der Merwe 2000).

    alpha, beta, kappa : spread of the sigma points, prior-shape weight, secondary scaling.
    """

    alpha: float = param(1.0, gt=0)
    beta: float = 2.0
    kappa: float = 0.0


@register_estimator
class SmeUKF(_SmeFilter):
    """SME under an unscented Kalman filter over the joint state (§4.2.3 check).

    Uses: as `sme-pf`, GNSS rows and the radar's topology.
    """

    name: ClassVar[str] = "sme-ukf"
    bound: ClassVar[str | None] = "oracle-pose"
    summary: ClassVar[str] = "symmetric measurement equation under an unscented Kalman filter (check)"
    Params: ClassVar[type[Params]] = SmeUKFParams

    def __init__(self, setup: Setup, params: SmeUKFParams, rng: np.random.Generator) -> None:
        super().__init__(setup, params, rng)
        self.params: SmeUKFParams = params
        self.mean = np.zeros((0, self.dx))       # (N, dx)
        self.cov = np.zeros((0, 0))              # (N dx, N dx) joint
        self._started = False

    def _moments(self) -> tuple[FloatArray, FloatArray]:
        n, dx = self.mean.shape
        blocks = self.cov.reshape(n, dx, n, dx)[np.arange(n), :, np.arange(n), :]
        return self.mean.copy(), symmetrize(blocks) + 1e-9 * np.eye(dx)

    def _sync(self, frame: Frame) -> None:
        present = np.sort(frame.vehicles)
        if np.array_equal(present, self.ids):
            return
        dx = self.mean.shape[1]
        keep = np.isin(self.ids, present)
        born = present[~np.isin(present, self.ids)]
        cols = (np.flatnonzero(keep)[:, None] * dx + np.arange(dx)).ravel()
        mean, cov = self.mean[keep], self.cov[np.ix_(cols, cols)]
        ids = self.ids[keep]
        if born.size:
            b_mean, b_cov = self._births(born, frame, mean[:, self.pos])
            mean = np.concatenate([mean, b_mean])
            m = cov.shape[0]
            grown = np.zeros((m + born.size * dx,) * 2)
            grown[:m, :m] = cov
            for i in range(born.size):  # few per step
                s = m + i * dx
                grown[s:s + dx, s:s + dx] = b_cov[i]
            cov, ids = grown, np.concatenate([ids, born])
        order = np.argsort(ids)
        cols = (order[:, None] * dx + np.arange(dx)).ravel()
        self.ids, self.mean, self.cov = ids[order], mean[order], cov[np.ix_(cols, cols)]

    def _sigma_points(self, mean: FloatArray, cov: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(2d + 1, N, dx) points and mean/covariance weights of the scaled UT of N(mean, cov)."""
        p = self.params
        d = cov.shape[0]
        lam = p.alpha**2 * (d + p.kappa) - d
        try:
            L = np.linalg.cholesky(symmetrize(cov) * (d + lam) + 1e-12 * np.eye(d))
        except np.linalg.LinAlgError:
            eig = np.linalg.eigvalsh(symmetrize(cov))
            raise EstimatorError(self.name, "the joint covariance has no Cholesky factor for the sigma "
                                 f"points (eigenvalues {eig[0]:.3g} … {eig[-1]:.3g}: too ill-conditioned "
                                 "for float64)") from None
        x = mean.ravel()
        points = np.concatenate([x[None], x + L.T, x - L.T])
        w_m = np.full(2 * d + 1, 0.5 / (d + lam))
        w_c = w_m.copy()
        w_m[0] = lam / (d + lam)
        w_c[0] = w_m[0] + 1 - p.alpha**2 + p.beta
        return points.reshape(2 * d + 1, *mean.shape), w_m, w_c

    def _unscented_update(self, mean: FloatArray, cov: FloatArray, model: PseudoMeasurement,
                          info: dict[str, Any]) -> tuple[FloatArray, FloatArray]:
        """The UKF update of N(mean (N, dx), cov (N dx, N dx)) with `model` (module docstring)."""
        points, w_m, w_c = self._sigma_points(mean, cov)
        y, Y, R = model.predict(points[:, :, self.pos])
        y_hat = w_m @ Y                                                  # ȳ = Σ W_m Y
        dY = Y - y_hat
        dX = points.reshape(points.shape[0], -1) - mean.ravel()
        S = symmetrize(np.einsum("s,si,sj->ij", w_c, dY, dY) + np.einsum("s,sij->ij", w_m, R))
        C = np.einsum("s,si,sj->ij", w_c, dX, dY)                        # cross-covariance
        # singular in float64 when its spectrum spans more than 1/ε: tested on the spectrum,
        # since whether `solve` meets an exact zero pivot there depends on the LAPACK build
        lam = np.linalg.eigvalsh(S) if np.isfinite(S).all() else np.full(1, np.nan)
        if not np.isfinite(lam).all() or lam[0] <= lam[-1] * S.shape[0] * np.finfo(float).eps:
            raise EstimatorError(self.name, "the innovation covariance of the pseudo-measurement "
                                 "(eq. 19) is singular: the sigma points' sums of powers lost all "
                                 "precision (a belief far from the rows, or covariances too far apart "
                                 "for float64)")
        K = np.linalg.solve(S, C.T).T                                    # K = C S⁻¹
        mean = (mean.ravel() + K @ (y - y_hat)).reshape(mean.shape)
        nis_sum, dof = info.get("nis", (0.0, 0))
        info["nis"] = (nis_sum + float(nis(y - y_hat, S)), dof + int(y.size))
        cov = symmetrize(cov - K @ S @ K.T)
        eig_min = np.linalg.eigvalsh(cov).min()
        if eig_min <= 1e-9:  # the UT lost positive definiteness: lift the spectrum
            cov = cov + (1e-9 - eig_min) * np.eye(cov.shape[0])
            info["covariance_repaired"] = True
        return mean, cov

    def _update_group(self, mean: FloatArray, cov: FloatArray, model: PseudoMeasurement
                      ) -> tuple[FloatArray, FloatArray]:
        """Per-radar mode: the UKF update of one group's independent blocks; their marginals."""
        n, dx = mean.shape
        mean, joint = self._unscented_update(mean, block_diagonal(cov), model, {})
        blocks = joint.reshape(n, dx, n, dx)[np.arange(n), :, np.arange(n), :]
        return mean, symmetrize(blocks)

    def step(self, frame: Frame) -> Estimate:
        if self.per_radar:
            return self._step_per_radar(frame)
        n = self.ids.size
        if n and self._started:
            # predict every block: m = A m, P = A P Aᵀ + Q (block diagonal)
            A = np.kron(np.eye(n), self.F)
            self.mean = self.mean @ self.F.T
            self.cov = symmetrize(A @ self.cov @ A.T + np.kron(np.eye(n), self.Q))
        self._started = True
        self._sync(frame)
        n = self.ids.size
        if n == 0:
            return Estimate(StateSet.empty(self.dx), None, {"set_valued": True, "skipped": []})
        mean, cov = self._moments()
        model, info = self._pseudo_measurement(frame, mean, cov)
        info["nis"] = (0.0, 0)
        if model.y_gnss is not None or model.y_radar is not None:
            self.mean, self.cov = self._unscented_update(self.mean, self.cov, model, info)
        return self._estimate(info)
