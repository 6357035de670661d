"""What both SME filters share: parameters, vehicles in and out, gating, eq. (19) per step.

Paper: Zhang et al. 2016 (``papers/001_80a6c560b7fdaa20.txt``), §3.3 and §4.2.1.

Model
-----
The joint state stacks the N present vehicles, x = [x¹; …; xᴺ] (eq. 1), each in
cooploc's layout of the setup (e.g. [p_x, p_y, v_x, v_y]); every block follows the
vehicles' motion model x_k = A x_{k−1} + w_k (eqs. 5–6, 16), with Q at rest where the
model's noise is state dependent. Each step `_SmeFilter._pseudo_measurement` turns the
frame into the `PseudoMeasurement` of eq. (19): the GPS sums of powers (eq. 17, per
axis or complex) and the radar topology (eq. 18), scaled by a centre and length fixed by
the predicted belief (``docs/sme.md``, "Numerical scaling").

Missed detections and clutter (§4.2.1 leaves them open)
-------------------------------------------------------
The SME map needs exactly N rows. When the setup has clutter (`Setup.clutter_rate` > 0)
or more than N rows arrive, GPS rows farther than the χ²₂ gate `gate_probability` from
every predicted vehicle (Mahalanobis, predicted covariance + row covariance) are dropped
as clutter. Without clutter, N rows are used as they come: gating them would let a
filter that drifted discard the rows that could bring it back. If the count of the
remaining GPS rows (resp. of the radar rows, which cannot be gated without the pose)
differs from N, that pseudo-measurement is skipped this step and the filter only
predicts with it; so is the radar's when its rows come from more than one radar (eq. 18
is the configuration in one radar's frame: rows of several road-side radars of
`sumo-*`, each in its own unknown frame, have no joint topology). `Estimate.info`
reports ``gnss_rows_used``, ``gnss_rows_gated`` and ``skipped`` (kinds skipped this step).

Zhang's GPS rows (the internal sensor) are of the position only, and eq. (17) sums powers
of positions. Where the setup's GNSS rows hold more (`sumo-*`'s z = [p, v] + w, 4×4
covariance), both filters take each row's exact position marginal, z_p = p + w_p with the
position block of its covariance (`base.position_fixes`), for the gate, eq. (17) and the
births — a choice: the rows' velocity information is not used. Rows without the position
are refused with a `ConfigError` at construction.

Vehicles that enter get a block from `Setup.vehicle_prior` if they have one (predicted
to the step), else a belief centred on the GPS row farthest from every predicted vehicle
with `default_birth_cov` velocity variance; vehicles that leave lose their block.

Estimates are set-valued: the vehicle blocks carry the ids of `frame.vehicles` in order,
but the measurements cannot tell vehicles apart, so ``info["set_valued"]`` is True and
metrics score them after an optimal assignment (`metrics.evaluate`).

Traffic: the per-radar mode
---------------------------
`mode` = "auto" keeps the joint filter above where the setup is the paper's (one radar
with an unbounded, all-around field: it sees every vehicle) and otherwise runs
`_step_per_radar` (`sumo-*`): the per-vehicle `gnss-kf` (identified GNSS rows used as
identified, odometry by stochastic cloning), then eq. (17) per gate group of anonymous
GPS rows and eq. (18) per radar over the vehicles it sees (modules `traffic`, `road_radars`), each
group updated by the filter's `_update_group` (unscented for `sme-ukf`, a Gaussian
particle filter for `sme-pf`). With no radar rows (and identified GNSS) that is
`gnss-kf` exactly. Eq. (18) corrects the means only: per-vehicle beliefs cannot hold
the correlations one scalar over M vehicles creates, and their shrunken marginals
without them would be overconfident (docs/sme.md, "In traffic"). Skipped radars and
their reasons: ``info["radar_skipped"]``; used: ``info["radars_used"]``.

Vehicles that enter together with anonymous rows: each is born on one of the rows the
others leave unexplained, but which row is whose the rows cannot say, while the odometry
rows, which name their vehicle, then move each belief by its own vehicle's displacement.
A vehicle born on another's row drifts out of every gate and is never updated again (run
3 of `sumo-grid-tlr`, 30 s, anonymous GNSS: 19.8 m). So at the next step the vehicles
born together are assigned to their birth beliefs by the joint likelihood of their first
odometry rows (`_seat_births`, optimal assignment over `gaussian.kf_update_relative`'s
likelihoods), before those rows are fused; ``info["births_reseated"]`` counts the moves.

Complexity per step: O(M N) for the gate of M GPS rows, O(N²) for the maps; per-radar
mode, O(n dx³) for the Kalman filters plus, per radar, O(M N) for its in-view set and
one group update of its M vehicles.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from cooploc.association import unexplained_rows
from cooploc.errors import EstimatorError
from cooploc.estimators.base import (
    birth_beliefs,
    checked_states,
    default_birth_cov,
    gnss_position_part,
    position_fixes,
)
from cooploc.estimators.road_radars import RadarFields, sees_every_vehicle, topology_nis
from cooploc.estimators.sme.pseudo_measurement import (
    PseudoMeasurement,
    complex_power_sums,
    power_sums,
    topology,
)
from cooploc.estimators.sme.traffic import gate_groups
from cooploc.gaussian import Gaussians, kf_update_relative
from cooploc.params import Params, param
from cooploc.sensors import InfrastructureRadar
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, Setup


@dataclass(frozen=True)
class _SmeParams(Params):
    """Parameters shared by both SME filters.

    form : "axes" — eq. (17), sums of powers of the x and of the y coordinates (the
        paper's); "complex" — sums of powers of x + i y (keeps which x goes with which y).

    min_scale : smallest length ℓ (m) of the position scaling.
    jitter : relative regularisation of the pseudo-measurement covariance.
    gate_probability : χ²₂ gate of GPS rows against the predicted vehicles (clutter).
    use_radar : use the topology pseudo-measurement of the radar (eq. 18).
    mode : "auto" — "joint" where the setup is the paper's (one radar whose field is
        unbounded: it sees every vehicle), "per-radar" otherwise; "joint" — one
        pseudo-measurement over all present vehicles (eq. 19); "per-radar" — traffic:
        eq. (18) per radar over the vehicles it sees, eq. (17) per gate group
        (`cooploc.estimators.sme.traffic`).
    view_confidence : per-radar mode: least probability that the vehicles taken as a
        radar's in-view set are exactly the ones it sees (else that radar is skipped).
    max_group : per-radar mode: largest group of anonymous GPS rows given one eq. (17).
    """

    form: Literal["axes", "complex"] = "complex"
    min_scale: float = param(10.0, gt=0)
    jitter: float = param(1e-9, ge=0, lt=1)
    gate_probability: float = param(0.9999, gt=0, lt=1)
    use_radar: bool = True
    mode: Literal["auto", "joint", "per-radar"] = "auto"
    view_confidence: float = param(0.9, gt=0, le=1)
    max_group: int = param(5, ge=1, le=10)


class _SmeFilter:
    """Bookkeeping of both SME filters: vehicles in and out, pseudo-measurements, gating."""

    # the GPS pseudo-measurement's density (`PseudoMeasurement.density`): the UKF uses its
    # moments only; `sme-pf` may take the exact density
    density: str = "gaussian"

    Params: ClassVar[type[Params]]
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "zhang2016-cv"
    required_sensors: ClassVar[tuple[str, ...]] = ("gnss", "radar")
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("anonymous-position", "gnss-position"), "radar": ("infrastructure-radar",),
        "odometry": ("odometry",)}

    def __init__(self, setup: Setup, params: _SmeParams, rng: np.random.Generator) -> None:
        self.setup = setup
        self.params = params
        self.rng = rng
        self.pos = list(setup.vehicle_layout.position)
        self.dx = setup.vehicle_layout.dim
        self.F = setup.vehicle_motion.transition_matrix(setup.dt)
        self.Q = setup.vehicle_motion.noise_covariance(setup.dt)
        if self.Q.ndim == 3:  # state-dependent noise: use its value at rest for the joint model
            self.Q = self.Q[0]
        self.ids: IntArray = np.zeros(0, np.int64)
        from scipy.stats import chi2  # here, not at import: `import cooploc` stays light

        self._gate = chi2.ppf(params.gate_probability, df=2)
        self._gate_1 = chi2.ppf(params.gate_probability, df=1)
        self._gnss_part = gnss_position_part(setup, self.name)
        radar = setup.sensors.get("radar")
        paper = sees_every_vehicle(setup)
        self.per_radar = params.mode == "per-radar" or (params.mode == "auto" and not paper)
        if self.per_radar:
            from cooploc.estimators.gnss_kf import GnssKF  # the no-radar filter it reduces to

            self._anonymous = getattr(setup.sensors.get("gnss"), "name", "") == "anonymous-position"
            self._base = GnssKF(setup, GnssKF.Params(), rng)
            self._fields = (RadarFields(radar, self._gate, params.view_confidence)
                            if isinstance(radar, InfrastructureRadar) else None)
            odometry = setup.sensors.get("odometry")
            self._H_odo = None if odometry is None else odometry.observation_matrix(self.dx)
            self._seats: IntArray = np.zeros(0, np.int64)   # vehicles that entered together last step

    def _gnss(self, frame: Frame) -> Batch | None:
        """The frame's GNSS rows as position fixes (module docstring)."""
        return position_fixes(frame.batches.get("gnss"), self._gnss_part)

    # -- to be provided by the filter ------------------------------------------------
    def _moments(self) -> tuple[FloatArray, FloatArray]:
        """(N, dx) mean and (N, dx, dx) covariance of each vehicle block."""
        raise NotImplementedError

    # -- shared ------------------------------------------------------------------------
    def _births(self, born: IntArray, frame: Frame, predicted: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean (b, dx) and cov (b, dx, dx) of entering vehicles (module docstring)."""
        beliefs = birth_beliefs(self.setup, born, frame)
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        unknown = np.flatnonzero(~np.isin(born, self.setup.vehicle_prior.ids))
        gnss = self._gnss(frame)
        if unknown.size and gnss is not None and len(gnss):
            z = gnss.z
            if predicted.shape[0]:
                dist = np.linalg.norm(z[:, None, :] - predicted[None, :, :], axis=-1).min(axis=1)
            else:
                dist = np.zeros(len(z))
            rows = np.argsort(-dist, kind="stable")[: unknown.size]
            for i, row in zip(unknown[: rows.size], rows, strict=False):
                mean[i] = 0.0
                mean[i, self.pos] = z[row]
                cov[i] = default_birth_cov(self.setup)
                cov[i][np.ix_(self.pos, self.pos)] = gnss.cov[row]
        return mean, cov

    def _pseudo_measurement(self, frame: Frame, mean: FloatArray, cov: FloatArray
                            ) -> tuple[PseudoMeasurement, dict[str, Any]]:
        """Build eq. (19) from the frame, gating GPS rows against the predicted vehicles."""
        n = mean.shape[0]
        p = mean[:, self.pos]
        centre = p.mean(axis=0)
        scale = max(float(np.sqrt(((p - centre) ** 2).sum(-1).mean())), self.params.min_scale)
        info: dict[str, Any] = {"skipped": [], "gnss_rows_used": 0, "gnss_rows_gated": 0}
        y_gnss, gnss_var = None, np.ones(2)
        gnss = self._gnss(frame)
        if gnss is not None and len(gnss):
            S = cov[:, self.pos][:, :, self.pos][None] + gnss.cov[:, None]          # (M, N, 2, 2)
            r = gnss.z[:, None, :] - p[None]
            d2 = np.einsum("mni,mni->mn", r, np.linalg.solve(S, r[..., None])[..., 0])
            keep = d2.min(axis=1) <= self._gate
            if len(gnss) == n and self.setup.clutter_rate == 0:
                keep[:] = True  # no clutter in the model: N rows are the N vehicles
            info["gnss_rows_gated"] = int((~keep).sum())
            if keep.sum() == n:
                z = gnss.z[keep]
                gnss_var = np.einsum("mii->mi", gnss.cov[keep]).mean(0) / scale**2
                u = (z - centre) / scale
                y_gnss = (complex_power_sums(u, n) if self.params.form == "complex"
                          else np.concatenate([power_sums(u[:, a], n) for a in range(2)]))
                info["gnss_rows_used"] = n
            else:
                info["skipped"].append("gnss")
        elif n:
            info["skipped"].append("gnss")
        y_radar, radar_var = None, 1.0
        radar = frame.batches.get("radar")
        if self.params.use_radar and radar is not None and len(radar):
            # eq. (18) is the topology of the N vehicles in *one* radar's frame: rows of
            # several radars (each in its own frame) that happen to number N are not
            if len(radar) == n and n >= 2 and np.unique(radar.sensor).size == 1:
                y_radar = float(topology(radar.z)) / scale**2
                # isotropic per-axis variance of each row: the rotation is unknown, so a
                # non-isotropic covariance is replaced by its mean eigenvalue
                radar_var = float(np.einsum("mii->m", radar.cov).mean() / 2) / scale**2
            else:
                info["skipped"].append("radar")
        elif self.params.use_radar and n:
            info["skipped"].append("radar")
        model = PseudoMeasurement(centre, scale, self.params.form, gnss_var, radar_var, y_gnss, y_radar,
                                  self.params.jitter, self.density)
        return model, info

    # -- per-radar mode (traffic) ---------------------------------------------------------
    def _update_group(self, mean: FloatArray, cov: FloatArray, model: PseudoMeasurement
                      ) -> tuple[FloatArray, FloatArray]:
        """Update the vehicles of one group, mean (n, dx) and cov (n, dx, dx) independent
        blocks, with its pseudo-measurement: the new means and marginal covariances."""
        raise NotImplementedError

    def _group_model(self, p: FloatArray, *, gnss_var: FloatArray | None = None,
                     rows: FloatArray | None = None, y_radar: float | None = None,
                     radar_var: float = 1.0) -> PseudoMeasurement:
        """Eq. (17) of GPS rows (global, (n, 2)) or eq. (18) of radar rows T, for the group
        at predicted positions p (n, 2), scaled as in the joint mode."""
        centre = p.mean(axis=0)
        scale = max(float(np.sqrt(((p - centre) ** 2).sum(-1).mean())), self.params.min_scale)
        n = p.shape[0]
        y_gnss = None
        if rows is not None:
            u = (rows - centre) / scale
            y_gnss = (complex_power_sums(u, n) if self.params.form == "complex"
                      else np.concatenate([power_sums(u[:, a], n) for a in range(2)]))
            gnss_var = gnss_var / scale**2
        return PseudoMeasurement(centre, scale, self.params.form,
                                 np.ones(2) if gnss_var is None else gnss_var, radar_var / scale**2,
                                 y_gnss, None if y_radar is None else y_radar / scale**2, self.params.jitter,
                                 self.density)

    def _seat_births(self, frame: Frame) -> int:
        """Vehicles that entered together at the previous step, moved to the rows their first
        odometry rows say are theirs; returns how many moved (module docstring, docs/sme.md).

        Their births took the rows no other vehicle explains, but which of those rows is
        whose the anonymous rows cannot say, so the pairing was arbitrary. The odometry row
        z_i = H x_k − H x_{k−1} + w names its vehicle: the seats (birth beliefs, each with
        the velocity of its row) are assigned to the vehicles by the largest joint
        likelihood Π_i q(z_i | seat π(i)) (`gaussian.kf_update_relative`), before the
        per-vehicle filter fuses those rows. A vehicle left on another's row would be moved
        by the wrong displacements, out of every row's gate, and never updated again.
        """
        seats, self._seats = self._seats, np.zeros(0, np.int64)
        odometry = frame.batches.get("odometry")
        if seats.size < 2 or self._H_odo is None or odometry is None or not len(odometry):
            return 0
        ids = self._base.vehicles.ids
        subjects, counts = np.unique(odometry.subject, return_counts=True)
        one_row = subjects[counts == 1]
        seats = seats[np.isin(seats, one_row) & np.isin(seats, frame.vehicles) & np.isin(seats, ids)]
        b = seats.size
        if b < 2:
            return 0
        at = np.searchsorted(ids, seats)
        row = np.flatnonzero(np.isin(odometry.subject, seats))
        row = row[np.argsort(odometry.subject[row], kind="stable")]           # row of seats[i]
        beliefs = self._base.vehicles.beliefs
        vehicle, seat = (g.reshape(-1) for g in np.meshgrid(np.arange(b), np.arange(b), indexing="ij"))
        previous = Gaussians(beliefs.mean[at[seat]], beliefs.cov[at[seat]])
        predicted = Gaussians(previous.mean @ self.F.T, self.F @ previous.cov @ self.F.T + self.Q)
        _, _, log_q = kf_update_relative(previous, predicted, self.F, odometry.z[row[vehicle]], self._H_odo,
                                         odometry.cov[row[vehicle]])
        from scipy.optimize import linear_sum_assignment

        _, choice = linear_sum_assignment(-log_q.reshape(b, b))                 # seat of each vehicle
        if np.array_equal(choice, np.arange(b)):
            return 0
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        mean[at], cov[at] = beliefs.mean[at[choice]], beliefs.cov[at[choice]]
        self._base.vehicles.beliefs = Gaussians(mean, cov)
        return int((choice != np.arange(b)).sum())

    def _step_per_radar(self, frame: Frame) -> Estimate:
        """One step in traffic (module `traffic`): the no-radar filter, then eq. (17) per GPS
        group (anonymous rows only) and eq. (18) per radar over the vehicles it sees."""
        reseated = self._seat_births(frame) if self._anonymous else 0
        before = self._base.vehicles.ids
        batches = dict(frame.batches)
        gnss = self._gnss(frame) if self._anonymous else None
        rows_full = frame.batches.get("gnss")
        if self._anonymous:
            batches.pop("gnss", None)   # the per-vehicle filter cannot use them; the groups do
        base = self._base.step(Frame(frame.k, frame.t, frame.vehicles, batches, frame.links))
        ids = self._base.vehicles.ids
        mean, cov = base.vehicles.mean.copy(), base.vehicles.cov.copy()
        info: dict[str, Any] = {"skipped": [], "gnss_rows_used": 0, "gnss_rows_gated": 0,
                                "radars_used": 0, "radar_skipped": {}, "gnss_groups_skipped": 0,
                                "births_reseated": reseated}
        pos = self.pos
        if self._anonymous and gnss is not None and len(gnss):
            born = np.flatnonzero(~np.isin(ids, before) & ~np.isin(ids, self.setup.vehicle_prior.ids))
            self._seats = ids[born] if born.size >= 2 else np.zeros(0, np.int64)
            H = self.setup.sensors["gnss"].observation_matrix(self.dx)
            S = (H @ cov @ H.T)[None] + rows_full.cov[:, None]                        # (M, N, dz, dz)
            r_full = rows_full.z[:, None, :] - (mean @ H.T)[None]
            d2 = np.einsum("mni,mni->mn", r_full, np.linalg.solve(S, r_full[..., None])[..., 0])
            if born.size:   # entering vehicles: on the rows the others explain least
                continuing = np.setdiff1d(np.arange(ids.size), born)
                rows = unexplained_rows(d2[:, continuing], born.size)
                cols = np.flatnonzero(H.any(axis=0))
                for i, row in zip(born[: rows.size], rows, strict=False):   # few per step
                    # every component the row measures (velocity too), the rest broad
                    mean[i] = 0.0
                    mean[i, cols] = rows_full.z[row]
                    cov[i] = default_birth_cov(self.setup)
                    cov[i][np.ix_(cols, cols)] = rows_full.cov[row]
                S = (H @ cov[born] @ H.T)[None] + rows_full.cov[:, None]
                r_full = rows_full.z[:, None, :] - (mean[born] @ H.T)[None]
                d2[:, born] = np.einsum("mni,mni->mn", r_full, np.linalg.solve(S, r_full[..., None])[..., 0])
            row_var = np.einsum("mii->m", gnss.cov) / 2
            from scipy.stats import chi2

            gate = chi2.ppf(self.params.gate_probability, df=H.shape[0])
            for v, r in gate_groups(d2, gate, self.params.max_group):
                if v.size == 0:
                    info["gnss_rows_gated"] += int(r.size)
                    continue
                if v.size != r.size or v.size > self.params.max_group:
                    info["gnss_groups_skipped"] += 1
                    continue
                model = self._group_model(mean[v][:, pos], gnss_var=np.full(2, row_var[r].mean()),
                                          rows=gnss.z[r])
                try:
                    mean[v], cov[v] = self._update_group(mean[v], cov[v], model)
                except EstimatorError:   # sums of powers beyond float64 at this size: skipped, counted
                    info["gnss_groups_skipped"] += 1
                    continue
                info["gnss_rows_used"] += int(r.size)
            if info["gnss_groups_skipped"]:
                info["skipped"].append("gnss")
        radar = frame.batches.get("radar")
        if self.params.use_radar and self._fields is not None and radar is not None and len(radar) \
                and ids.size:
            for sensor in np.unique(radar.sensor):
                rows = np.flatnonzero(radar.sensor == sensor)
                q = radar.z[rows]
                p = mean[:, pos]
                var = np.einsum("nii->n", cov[:, pos][:, :, pos]) / 2
                seen, reason = self._fields.in_view(int(sensor), q, p, var)
                if seen is not None and seen.size < 2:
                    seen, reason = None, "fewer than two vehicles in view (eq. 18 is then 0)"
                if seen is not None:
                    T = float(topology(q))
                    radar_var = float(np.einsum("mii->m", radar.cov[rows]).mean() / 2)
                    if topology_nis(p[seen], var[seen], T, radar_var) > self._gate_1:
                        seen, reason = None, "its topology lies outside the gate of the beliefs"
                if seen is None:
                    info["radar_skipped"][int(sensor)] = reason
                    continue
                model = self._group_model(p[seen], y_radar=T, radar_var=radar_var)
                try:
                    # T corrects the means; the covariances stay as predicted (module docstring)
                    mean[seen], _ = self._update_group(mean[seen], cov[seen], model)
                except EstimatorError as exc:
                    info["radar_skipped"][int(sensor)] = str(exc)
                    continue
                info["radars_used"] += 1
            if info["radar_skipped"]:
                info["skipped"].append("radar")
        self._base.vehicles.beliefs = Gaussians(mean, cov)
        self.ids = ids
        info["set_valued"] = self._anonymous
        info["nis"] = base.info.get("nis", (0.0, 0))
        return Estimate(checked_states(self.name, "vehicle", ids, mean, cov), None, info)

    def _estimate(self, info: dict[str, Any]) -> Estimate:
        mean, cov = self._moments()
        info["set_valued"] = True
        return Estimate(checked_states(self.name, "vehicle", self.ids, mean, cov), None, info)
