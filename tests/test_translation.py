"""Far from the origin, the same estimates (issue 16, item 2).

Real data in UTM (10⁵…10⁶ m) or ECEF (6·10⁶ m) coordinates must give the estimates
that the same data near the origin gives. Every estimator that accepts a paper preset
runs a short recording of it twice — as generated, and `translated` by 10⁶ m on each
axis — with the same seed; the far estimates, moved back, must equal the near ones.

Tolerance: float64 represents 10⁶ m to 1.2·10⁻¹⁰ m, and the Kalman-type estimators agree
to ~10⁻⁹ m. Particle filters with resampling (icp-da-pf) and the SME-UKF on gulati-2v
amplify round-off step by step (their filters are sensitive to the last bit, near the
origin too), reaching ~2·10⁻⁴ m after 6 steps; `MEAN_ATOL` = 1 mm is two orders below
that growth's margin and three below the smallest sensor noise (σ = 0.1 m of froehle2018's
good GNSS), so an estimator that loses metres (float32 or absolute-position numerics,
e.g. the pair kernel before it was centred: 2·10⁻² relative error at 5·10⁵ m) fails.
"""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.experiment import estimate
from cooploc.registry import estimators, make_estimator
from cooploc.testing import preset_recording, translated

OFFSET = np.array([1e6, -1e6])
MEAN_ATOL = 1e-3          # m, see the module docstring
COV_RTOL = 1e-4           # relative to the largest covariance entry of the step
PAPER_PRESETS = ["froehle2018", "zhang2016-cv", "gulati-2v", "aoa-grid", "brambilla-road"]
#: known not translation-invariant for a reason outside numerics (see the report of issue 16)
IGNORES_THE_DATA: dict[tuple[str, str], str] = {}
#: cases slower than ~2 s
SLOW = {("aoa-grid", "plbp"), ("froehle2018", "rsu-bp"), ("zhang2016-cv", "sme-pf")}


def cases() -> list:
    out = []
    for preset in PAPER_PRESETS:
        for name in sorted(estimators()):
            marks = [pytest.mark.slow] if (preset, name) in SLOW else []
            out.append(pytest.param(preset, name, marks=marks, id=f"{preset}-{name}"))
    return out


@pytest.mark.parametrize(("preset", "name"), cases())
def test_estimates_do_not_depend_on_where_the_origin_is(preset: str, name: str) -> None:
    near = preset_recording(preset, 0, None if preset == "aoa-grid" else {"n_steps": 6})
    far = translated(near, OFFSET)
    try:
        a = make_estimator(name, near.setup, None, np.random.default_rng(5), truth=near.truth)
    except ConfigError:
        return  # the estimator does not apply to this preset (refused as it should be)
    if (preset, name) in IGNORES_THE_DATA:
        return
    b = make_estimator(name, far.setup, None, np.random.default_rng(5), truth=far.truth)
    position = list(near.setup.vehicle_layout.position)
    for k, (x, y) in enumerate(zip(estimate(a, near), estimate(b, far), strict=True)):
        np.testing.assert_array_equal(y.vehicles.ids, x.vehicles.ids, err_msg=f"step {k}")
        back = np.array(y.vehicles.mean)
        back[:, position] -= OFFSET
        np.testing.assert_allclose(back, x.vehicles.mean, rtol=0, atol=MEAN_ATOL,
                                   err_msg=f"{name} on {preset}, step {k}: means")
        if len(x.vehicles):
            np.testing.assert_allclose(y.vehicles.cov, x.vehicles.cov, rtol=0,
                                       atol=COV_RTOL * np.abs(x.vehicles.cov).max(),
                                       err_msg=f"{name} on {preset}, step {k}: covariances")
