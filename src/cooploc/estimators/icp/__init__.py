"""Implicit cooperative positioning (ICP), distributed over vehicles — Brambilla et al. 2020.

Paper: "Augmenting Vehicle Localization by Cooperative Sensing of the Driving
Environment: Insight on Data Association in Urban Traffic Scenarios"
(`papers/003_dd51a52f1e371d91.txt`). Vehicles
localize themselves (GNSS, eq. 3) and passive features they sense (V2F relative
position and velocity, eq. 4) by belief propagation over the V2V network; the feature
beliefs, which no feature can compute, are computed by consensus among the vehicles.

Three estimators, one module each, each building on the one before:

- `gaussian_bp` — `icp`: known association, Gaussian BPA-L (eqs. 19–22) with
  consensus; every agent's copies of the feature beliefs, their prediction (12) and
  sharing. By default each step's BPA-L fuses that step's V2F rows only, from the
  GNSS-only vehicle filters and uniform feature priors; the paper's recursion over
  steps (11)–(12) is switched on by `feedback` and `feature_memory`: that module's
  docstring says what runs, and why the defaults are what they are.
- `data_association` — `icp-da-lc`: BPA-DA (13)–(17) at each vehicle, MAP pairing with
  a threshold (30), births of new features agreed by flooding, then the Gaussian BPA-L;
  before (13) each vehicle locates itself against the tracks it holds from all its rows
  jointly (`registration`, a departure from the paper that its docstring explains).
- `particle_bp` — `icp-da-pf`: the same association with soft pairings (18) and a
  particle BPA-L (23)–(29) with log-likelihood consensus (`cooploc.particles`).

Derivations and the reasons behind the defaults: docs/icp.md. Speed and V2V traffic:
`benchmarks/icp.py`; accuracy against the paper: `cooploc reproduce brambilla2020`.
"""

from cooploc.estimators.icp.data_association import BIRTH_GATE, BIRTH_ID_BASE, ICPDALC, ICPDALCParams
from cooploc.estimators.icp.gaussian_bp import ICP, ICPParams, relative_message
from cooploc.estimators.icp.particle_bp import ICPDAPF, ICPDAPFParams

__all__ = [
    "BIRTH_GATE",
    "BIRTH_ID_BASE",
    "ICP",
    "ICPDALC",
    "ICPDAPF",
    "ICPDALCParams",
    "ICPDAPFParams",
    "ICPParams",
    "relative_message",
]
