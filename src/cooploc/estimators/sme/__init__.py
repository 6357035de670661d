"""`sme-pf`, `sme-ukf`: the symmetric measurement equation (SME) filter of Zhang et al. 2016.

Paper: Zhang, Hinz, Gulati, Clarke & Knoll, GeoInformatica 2016, §3.2–3.3
(``papers/001_80a6c560b7fdaa20.txt``); SME after Kamen 1992 and Leven & Lanterman 2004.

Anonymous GPS rows become sums of powers (eq. 17) and radar rows of unknown pose the
topology of the vehicles (eq. 18), both symmetric in the vehicles, so the joint state
x = [x¹; …; xᴺ] (eq. 1) is filtered without data association through the stacked
pseudo-measurement of eq. (19). Derivation of its noise moments: ``docs/sme.md``.

The problem apart from the filters that use it:

- `pseudo_measurement` — the symmetric maps, their exact Gaussian noise moments,
  Newton's identities, and `PseudoMeasurement` (eq. 19 of one step, weighed by the
  Gaussian pseudo-noise or by the exact density of the sums of powers; its numba
  likelihood kernels live in the private `_kernels`, compiled on first use);
- `filter_base` — what both filters share: parameters, vehicles entering and leaving,
  GPS gating against clutter, the per-step assembly of eq. (19), and the two modes:
  ``"joint"`` (the paper's: one radar that sees every vehicle, `zhang2016-*`) and
  ``"per-radar"`` (traffic, `sumo-*`: the `gnss-kf` filter, then eq. 18 per radar over the
  vehicles it sees and eq. 17 per gate group of anonymous GPS rows);
- `traffic` — which vehicles each radar sees (its pose registered and tracked by the
  estimator) and the gate groups of anonymous rows;
- `pf` — `sme-pf` (`SmePF`, `SmePFParams`): the paper's particle filter, by default with
  the linearized optimal proposal of `proposal` (an auxiliary particle filter) over the
  positions only, the velocities marginalized (`marginalized`), or drawing the whole
  state from the motion model (``proposal="bootstrap"``);
- `proposal` — the linearized proposal: eq. (19) linearized by statistical linear
  regression over the predicted cloud, each particle's Kalman posterior under it;
- `marginalized` — the velocities of the Rao–Blackwellised (marginalized) particle
  filter: per particle a Gaussian given its sampled positions (Schön et al. 2005);
- `ukf` — `sme-ukf` (`SmeUKF`, `SmeUKFParams`): the §4.2.3 check under a UKF.

The particle toolkit (resampling, effective sample size, moments) is
`cooploc.particles`.
"""

from __future__ import annotations

from cooploc.estimators.sme.pf import SmePF, SmePFParams
from cooploc.estimators.sme.pseudo_measurement import (
    PseudoMeasurement,
    complex_points_from_power_sums,
    complex_power_sum_moments,
    complex_power_sums,
    gaussian_raw_moments,
    points_from_power_sums,
    power_sum_moments,
    power_sums,
    topology,
    topology_moments,
)
from cooploc.estimators.sme.ukf import SmeUKF, SmeUKFParams

__all__ = [
    "PseudoMeasurement",
    "SmePF",
    "SmePFParams",
    "SmeUKF",
    "SmeUKFParams",
    "complex_points_from_power_sums",
    "complex_power_sum_moments",
    "complex_power_sums",
    "gaussian_raw_moments",
    "points_from_power_sums",
    "power_sum_moments",
    "power_sums",
    "topology",
    "topology_moments",
]
