"""Zhang, Hinz, Gulati, Clarke & Knoll 2016 (GeoInformatica), §4.1: five vehicles, one radar.

Model (paper §3.3 and §4.1)
---------------------------
- Five vehicles on the ground plane with the initial states of §4.1, T = 1 s. They
  move with the constant-velocity model, or the constant-turn model of eq. (14) for
  some of them; process noise of standard deviation δ = 0.5 (white acceleration of
  density δ² = 0.25 m²/s³, the Q of eq. (14) and its ω → 0 limit).
- Internal sensor (GPS of each vehicle): z = p + w, w ~ N(0, diag(0.5, 0.5)) m². The
  rows reach the fusion centre anonymously and shuffled (`AnonymousPosition`, batch
  kind ``"gnss"``): the association is unknown.
- External sensor (road-side radar): every vehicle's position in the radar's own frame,
  z = R(θ)ᵀ(p − t) + w, w ~ N(0, diag(0.1, 0.1)) m², anonymous and shuffled
  (`InfrastructureRadar`, kind ``"radar"``, radar id 100). Its pose (t, θ) is random
  per run and unknown to the estimators (kept in `Truth.sensor_poses`).
- Presets: ``zhang2016-cv`` (all CV), ``zhang2016-ct2`` (two vehicles turn),
  ``zhang2016-ct4`` (four vehicles turn).

State layout
------------
The paper orders a state as [p_x, ṗ_x, p_y, ṗ_y]; cooploc's vehicles use
[p_x, p_y, v_x, v_y] (`StateLayout.position_velocity`, the layout of `motion.py`), so
the paper's x_1 = [0, −1.5, 100, −1]ᵀ is our [0, 100, −1.5, −1]. Positions are
components (0, 1). Paper vehicle i is our vehicle id i − 1.

Choices the paper leaves open (parameters of `ZhangParams`)
-----------------------------------------------------------
- ω = ±0.05° "per step": we read it as ±0.05 **rad** per step (0.05 rad/s at T = 1 s).
  With 0.05°/s a vehicle at 1.8 m/s drifts less than 8 m from its straight line in
  100 s — on the 300 m wide plot of Fig. 2 the CT scenarios would look like the CV one,
  and the CV-model filters could not "degrade a lot" in CT-4 (§4.1). With 0.05 rad/s
  the turning vehicles follow visible arcs (radius v/ω ≈ 36 m). `turn_rates` is in
  rad/s; set it to ±0.000873 for the degree reading.
- Which vehicles turn, and which way: CT-2 turns paper vehicles 1 (+ω) and 5 (−ω), the
  two that start at y = 100 m; CT-4 also turns vehicles 2 (−ω) and 4 (+ω). Vehicle 3
  always goes straight. The signs mirror the scene about x = 0, as its initial states do.
- Run length: 100 steps. Vehicles 1/2 and 4/5 cross at step 50 (the hard case for
  anonymous measurements), and the scene spans ≈ 300 m as in Fig. 2.
- The true trajectories are the noise-free CV / CT paths from the §4.1 states
  (`truth_noise_std` = 0). With the filters' δ = 0.5 as *true* process noise the
  velocities would random-walk by 5 m/s in 100 s — more than the 1.5–3 m/s of the
  initial states — and Fig. 2's pattern of crossing lines could not arise. δ = 0.5 is
  the estimators' process noise model (`Setup.vehicle_motion`); set `truth_noise_std`
  to simulate noisy trajectories.
- The trajectories start exactly at the §4.1 states. Estimators get them as the prior
  mean with covariance diag(2.5, 2.5, 1, 1) — our reading of "Q is initialed as
  diag[2.5, 1, 2.5, 1, …]", which as a process noise would contradict δ = 0.5.
- Estimators model every vehicle with the CV model (`Setup.vehicle_motion`): the turn
  rates are not known to them (eq. 14 has one A for all vehicles, which cannot hold
  when they turn in different directions). In CT scenarios this is the model mismatch
  the paper discusses in §4.1.
- Radar pose: t uniform in [−`radar_extent`, `radar_extent`]² m, θ uniform in [−π, π).
- Missed detections and clutter (§4.2.1 leaves them open, the paper has none): each row
  is detected with `detection_probability`; Poisson(`clutter_rate`) clutter rows per
  sensor and step, uniform over `Setup.clutter_region` (GPS, global frame:
  x ∈ [−200, 200], y ∈ [−100, 400] m) or over a box of half-width `radar_clutter_extent`
  in the radar's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.budget import Sizes
from cooploc.motion import ConstantTurn, ConstantVelocity
from cooploc.params import Params, param
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios import limits
from cooploc.sensors import AnonymousPosition, InfrastructureRadar
from cooploc.types import Frame, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["GNSS_CLUTTER_REGION", "INITIAL_STATES_PAPER", "PRESETS", "RADAR_ID", "ZhangParams",
           "generate", "initial_states"]

#: §4.1 initial states in the paper's order [p_x, ṗ_x, p_y, ṗ_y].
INITIAL_STATES_PAPER = np.array([
    [0.0, -1.5, 100.0, -1.0],
    [0.0, -1.5, 0.0, 1.0],
    [0.0, 0.0, 0.0, 3.0],
    [0.0, 1.5, 0.0, 1.0],
    [0.0, 1.5, 100.0, -1.0],
])
RADAR_ID = 100
GNSS_CLUTTER_REGION = np.array([[-200.0, 200.0], [-100.0, 400.0]])
_PAPER_TO_COOPLOC = [0, 2, 1, 3]  # [p_x, ṗ_x, p_y, ṗ_y] → [p_x, p_y, v_x, v_y]


def initial_states(n_vehicles: int = 5) -> np.ndarray:
    """(n, 4) §4.1 initial states of the first n vehicles in cooploc's [p_x, p_y, v_x, v_y]."""
    return INITIAL_STATES_PAPER[:n_vehicles][:, _PAPER_TO_COOPLOC].copy()


@dataclass(frozen=True)
class ZhangParams(Params):
    """Parameters of the Zhang 2016 scenario; defaults are §4.1 (CV).

    Attributes
    ----------
    n_vehicles : the first n of the paper's five vehicles (1..5).
    n_steps : steps of T = `dt` s (our choice: 100, see module doc).
    dt : T in s.
    process_noise_std : δ (m/s^1.5) of the estimators' motion model, density δ².
    truth_noise_std : δ of the simulated trajectories (0: the noise-free paths of Fig. 2).
    turn_rates : ω in rad/s per vehicle (empty or shorter = the rest go straight).
    gnss_variance : variance (m²) per axis of the internal sensor.
    radar_variance : variance (m²) per axis of the external sensor.
    prior_position_variance, prior_velocity_variance : the estimators' prior (m², m²/s²).
    radar_extent : half-width (m) of the square the radar position is drawn from.
    detection_probability : P_D of each row of each sensor (paper: 1).
    clutter_rate : mean clutter rows per sensor and step (paper: 0).
    radar_clutter_extent : half-width (m) of the radar-frame clutter box.
    """

    n_vehicles: int = param(5, ge=1, le=5)
    n_steps: int = param(100, ge=1)
    dt: float = param(1.0, gt=0, le=limits.STEP)
    process_noise_std: float = param(0.5, ge=limits.STD_MIN, le=limits.ACCELERATION)
    truth_noise_std: float = param(0.0, ge=0, le=limits.ACCELERATION)
    turn_rates: tuple[float, ...] = param((), finite=True, must="be finite")
    gnss_variance: float = param(0.5, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    radar_variance: float = param(0.1, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    prior_position_variance: float = param(2.5, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    prior_velocity_variance: float = param(1.0, ge=limits.VARIANCE_MIN, le=limits.SPEED_VARIANCE)
    radar_extent: float = param(100.0, gt=0, le=limits.LENGTH)
    detection_probability: float = param(1.0, gt=0, le=1)
    clutter_rate: float = param(0.0, ge=0, le=limits.CLUTTER_RATE)
    radar_clutter_extent: float = param(300.0, gt=0, le=limits.LENGTH)

    def validate(self) -> None:
        # 0 is the noise-free paths; a spread below STD_MIN squares to a singular covariance
        self.require(self.truth_noise_std == 0 or self.truth_noise_std >= limits.STD_MIN, "truth_noise_std",
                     f"be 0 or lie in [{limits.STD_MIN:g}, {limits.ACCELERATION:g}]")
        self.require(len(self.turn_rates) <= self.n_vehicles, "turn_rates",
                     f"have at most n_vehicles = {self.n_vehicles} entries")

    def sizes(self) -> Sizes:
        """Steps, vehicles and features of one run (for `cooploc.budget`)."""
        return Sizes(self.n_steps, self.n_vehicles)

    def turn_rate_of(self, vehicle: int) -> float:
        return self.turn_rates[vehicle] if vehicle < len(self.turn_rates) else 0.0


def generate(params: ZhangParams, rng: np.random.Generator) -> Recording:
    """Simulate one run of the scenario."""
    N, T, dt = params.n_vehicles, params.n_steps, params.dt
    density = params.process_noise_std**2
    ids = np.arange(N, dtype=np.int64)
    rng_motion, rng_pose, rng_gnss, rng_radar = rng.spawn(4)

    # eq. (14) per vehicle (ω = 0: CV); the noise is the same white acceleration for all
    F = np.stack([ConstantTurn(params.turn_rate_of(i), density).transition_matrix(dt)
                  for i in range(N)])                                           # (N, 4, 4)
    Q = ConstantVelocity(params.truth_noise_std**2).noise_covariance(dt)
    noise = np.zeros((max(T - 1, 0), N, 4))
    if params.truth_noise_std > 0:
        noise = rng_motion.standard_normal((max(T - 1, 0), N, 4)) @ np.linalg.cholesky(Q).T
    states = np.empty((T, N, 4))
    states[0] = initial_states(N)
    for k in range(1, T):  # eq. (16): x_k = A x_{k−1} + w_k
        states[k] = np.einsum("nij,nj->ni", F, states[k - 1]) + noise[k - 1]

    pose = np.array([*rng_pose.uniform(-params.radar_extent, params.radar_extent, 2),
                     rng_pose.uniform(-np.pi, np.pi)])
    gnss = AnonymousPosition(default_cov=params.gnss_variance * np.eye(2))
    radar = InfrastructureRadar(default_cov=params.radar_variance * np.eye(2))
    e = params.radar_clutter_extent
    radar_region = np.array([[-e, e], [-e, e]])
    clutter = {"detection_probability": params.detection_probability,
               "clutter_rate": params.clutter_rate}

    frames, origins = [], []
    for k in range(T):
        gnss_batch, gnss_origin = gnss.measure(ids, states[k], rng_gnss,
                                               clutter_region=GNSS_CLUTTER_REGION, **clutter)
        radar_batch, radar_origin = radar.measure(RADAR_ID, pose, ids, states[k], rng_radar,
                                                  clutter_region=radar_region, **clutter)
        frames.append(Frame(k, k * dt, ids, {"gnss": gnss_batch, "radar": radar_batch}))
        origins.append({"gnss": gnss_origin, "radar": radar_origin})

    prior_cov = np.diag([params.prior_position_variance] * 2 + [params.prior_velocity_variance] * 2)
    turning = sum(params.turn_rate_of(i) != 0 for i in range(N))
    setup = Setup(
        dt=dt,
        n_steps=T,
        vehicle_layout=StateLayout.position_velocity(2),
        vehicle_motion=ConstantVelocity(density),
        vehicle_prior=StateSet(ids, initial_states(N), np.repeat(prior_cov[None], N, 0)),
        sensors={"gnss": gnss, "radar": radar},
        detection_probability=params.detection_probability,
        clutter_rate=params.clutter_rate,
        clutter_region=GNSS_CLUTTER_REGION,
        infrastructure_ids=(RADAR_ID,),
        description=f"Zhang 2016 §4.1: {N} vehicles ({turning} turning), anonymous GPS and "
                    f"a radar of unknown pose, {T} steps of {dt} s",
    )
    truth = Truth.always_present(ids, states, origins, sensor_poses=pose[None])
    return Recording(setup, frames, truth)


_OMEGA = 0.05  # rad/s, §4.1 "ω = ±0.05°" read as radians per step (module doc)
_DOC = ("Reproduces Figs. 2–3 of Zhang et al. (GeoInformatica 2016): five vehicles, anonymous "
        "GPS diag(0.5, 0.5) m², a radar of unknown pose diag(0.1, 0.1) m², 100 steps of 1 s.")

PRESETS = register_scenario("zhang2016", generate, [
    Preset("zhang2016-cv", ZhangParams(),
           "Zhang 2016 §4.1 CV: 5 vehicles, anonymous GPS + radar of unknown pose", _DOC,
           bound="oracle-pose"),
    Preset("zhang2016-ct2", ZhangParams(turn_rates=(_OMEGA, 0.0, 0.0, 0.0, -_OMEGA)),
           "Zhang 2016 §4.1 CT-2: vehicles 1 and 5 turn at ±0.05 rad/s", _DOC, bound="oracle-pose"),
    Preset("zhang2016-ct4", ZhangParams(turn_rates=(_OMEGA, -_OMEGA, 0.0, _OMEGA, -_OMEGA)),
           "Zhang 2016 §4.1 CT-4: vehicles 1, 2, 4, 5 turn at ±0.05 rad/s", _DOC, bound="oracle-pose"),
])
