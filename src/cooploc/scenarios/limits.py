"""Physical limits of scenario parameters (issue 16, item 6).

Scenario `Params` declare these as the bounds of their fields (`param(..., le=LENGTH)`),
so that a value no road scenario can mean is refused with the valid range, instead of
overflowing float64 deep inside a simulation or a filter (`dt = 1e300` cubed in the
process noise, a start spread of 1e200 m squared in a covariance). Each limit lies far
beyond physics and far inside float64: squares and cubes of bounded values, and their
products with each other, stay finite. Sizes (steps, vehicles, features) are not bounded
here; `cooploc.budget` checks them against the machine's memory.
"""

from __future__ import annotations

import math

#: m — any length: position spreads, ranges, extents. Earth's circumference is 4·10⁷ m,
#: so no distance between two places on Earth is longer; its square (1.6·10¹⁵ m²) is a
#: position variance nothing exceeds.
LENGTH = 4e7
#: m² — a position variance: LENGTH².
LENGTH_VARIANCE = LENGTH**2
#: m, m/s, rad — the smallest standard deviation: below any sensor's resolution, and its
#: square (10⁻¹²) is still a normal float whose inverse is finite.
STD_MIN = 1e-6
#: m², m²/s², rad² — the smallest variance, STD_MIN².
VARIANCE_MIN = STD_MIN**2
#: m/s — any speed or speed spread: three times the speed of sound, beyond any road user.
SPEED = 1e3
#: m²/s² — a velocity variance: SPEED².
SPEED_VARIANCE = SPEED**2
#: s — the longest step between frames: an hour; dt³ in a process noise stays finite.
STEP = 3600.0
#: s — simulated time of traffic (SUMO's duration, warmup, trip periods): a day; traffic
#: settles within minutes, and a day of 0.75-s steps is already 115 200 steps.
DAY = 86400.0
#: m²/s³ — white-acceleration noise density: 10⁴ is an acceleration of 100 m/s² (10 g)
#: per √s, beyond any vehicle.
NOISE_DENSITY = 1e4
#: m/s² — an acceleration spread: 10 g.
ACCELERATION = 100.0
#: rad — an angle spread: a full turn; larger carries no more information.
ANGLE = 2 * math.pi
#: rad² — an angle variance: ANGLE².
ANGLE_VARIANCE = ANGLE**2
#: rows per sensor and step — mean clutter: beyond 10⁴ false rows a step no association
#: is meaningful and the rows alone fill memory.
CLUTTER_RATE = 1e4
