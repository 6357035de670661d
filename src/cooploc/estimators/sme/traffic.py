r"""SME in traffic: which vehicles each road-side radar sees, and the groups of anonymous GPS rows.

Paper: Zhang, Hinz, Gulati, Clarke & Knoll, GeoInformatica 2016 (``papers/001_80a6c560b7fdaa20.txt``)
assume one radar that sees all N vehicles, N known (§3.2, §4.1). In traffic (`sumo-*`)
several radars stand at junctions, each sees the few vehicles within its range and field
of view, and vehicles enter and leave. The symmetric-measurement idea is kept and applied
where it holds: the topology pseudo-measurement of eq. (18) per radar, over the vehicles
*that radar* sees (its row count is the N of that radar), and the sums of powers of
eq. (17) per group of anonymous GPS rows that only a group of vehicles can explain (the
"SME filters in parallel" of the paper's §5 outlook, refs. [26, 27]).

Which vehicles a radar sees: `cooploc.estimators.road_radars.RadarFields` (shared with
the factor graphs), registration of each radar's unknown pose from the estimator's
own beliefs, tracking, and the in-view set.

Anonymous GPS groups (`gate_groups`)
------------------------------------
With anonymous GPS rows in traffic the N of eq. (17) would be every vehicle in the city
(polynomials of order 30 and more, which the paper's §4.2.3 already finds hopeless at
10). Rows and predicted vehicles are linked where a row lies within the gate of a vehicle
(squared Mahalanobis distance over every component the row measures — velocity too,
which tells a stopped queue from the traffic passing it — against the χ² quantile of
`gate_probability` with that many degrees of freedom); each connected component of
that bipartite graph is one SME group (a group larger than `max_group` is split again
with half the gate, down to a gate of 2). Vehicles that enter are placed on the rows an
optimal assignment to the other vehicles leaves unexplained
(`association.unexplained_rows`), with every component the row measures. A group
with as many rows as vehicles and at most `max_group` of them gets its own eq. (17)
update (one vehicle and one row: the complex power sum s₁ = x + i y is the row itself,
a Kalman update); other groups are skipped with the reason recorded.

Complexity: `gate_groups` O(M N) per step.
"""

from __future__ import annotations

import numpy as np

from cooploc.association import pair_components
from cooploc.estimators.road_radars import RadarFields
from cooploc.types import FloatArray, IntArray

__all__ = ["RadarFields", "gate_groups"]


def gate_groups(d2: FloatArray, gate: float, max_size: int | None = None) -> list[tuple[IntArray, IntArray]]:
    """The SME groups of M anonymous rows and N vehicles: connected components of the gate
    graph, as (vehicles, rows), from the squared Mahalanobis distances d2 (M, N).

    A row and a vehicle are linked where d2 ≤ gate. A group of more than `max_size`
    vehicles or rows is split again with half the gate, down to a gate of 2, so that dense
    traffic still gives groups of a size eq. (17) can hold.
    """
    M, N = d2.shape
    r, v = np.nonzero(d2 <= gate)
    label = pair_components(M + N, r, M + v)                  # rows 0…M−1, then the vehicles
    groups = []
    for g in np.unique(label):
        rows, vehicles = np.flatnonzero(label[:M] == g), np.flatnonzero(label[M:] == g)
        if max_size is not None and max(rows.size, vehicles.size) > max_size and gate > 2.0:
            inner = gate_groups(d2[np.ix_(rows, vehicles)], gate / 2, max_size)
            groups.extend((vehicles[iv], rows[ir]) for iv, ir in inner)
        else:
            groups.append((vehicles, rows))
    return groups
