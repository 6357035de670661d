"""`oracle-kf` in component form: one dense covariance per connected component of the coupling.

The filter is the dense joint one (`dense`, the package docstring); this is the same
filter with the zeros of its covariance left out.

Why components, and not a sparse information filter
---------------------------------------------------
Two entities (vehicles, features) are correlated once a V2F row has linked them,
directly or through other entities; the correlation then decays under process noise
and GNSS but never vanishes exactly. An information matrix does not stay sparse
either: the prediction marginalises the previous state, which fills the information
matrix in over every coupled set. So the exact structure is: the joint covariance is
block diagonal over the connected components of the coupling graph and dense inside
each. A V2F row between two components merges them; a component shrinks when its
vehicles leave and its features time out (marginalising is dropping rows and columns,
exact); it never splits (the entities left stay correlated). A vehicle no V2F row has
linked yet is alone: the alone vehicles are independent Gaussians kept as one stack
(each a `gnss-kf` of its own) and predicted and updated in one batch.

One step
--------
1. Marginalise out the vehicles that left and the features unseen for
   `feature_timeout` steps.
2. Clone for the odometry (where the scenario has it; Gulati eq. 4,
   z = H x_k − H x_{k−1} + w), stochastic cloning: every vehicle of a component with an
   odometry row gets its clone c = H x_{k−1} appended to the component — an entity of
   kind CLONE, with mean H x and the rows and columns A P, A P Aᵀ of the joint
   (`_with_clones`), so correlated with everything the vehicle is. An alone vehicle with
   one row keeps its belief at k − 1 and is updated by `gaussian.kf_update_relative`
   before its GNSS row (exact: it is independent of all else); promoted to a component
   this step (step 4), it takes its clone along; with several rows it becomes a
   component first. Then predict each component with the block-diagonal motion model,
   P⁻ = F P Fᵀ + Q block by block (a clone is static: identity, no noise, so its
   cross-covariance becomes F P Aᵀ): O(D² d) for D states of entities of dimension d, not
   the O(D³) of a dense F (`_matrix_kernels.congruence_blocks`: one pass over P, each
   block F_a P_ab F_bᵀ written to both triangles, so P⁻ is exactly symmetric). Q of every
   component's entities comes from one call of the motion model.
3. Append the entering vehicles (alone) and the features seen for the first time
   (`births`), each a component of its own.
4. Merge the components that this step's V2F rows link (connected components of the
   graph whose nodes are the components and whose edges are the rows).
5. Update each component with its rows — GNSS, V2F and odometry (z = H x_k − c + w) — in
   information form, on the r coordinates the rows observe, y = Eᵀθ (the position of
   each observed entity, all of a clone); the clones are then marginalised out
   (dropped). The rows add
   J = Σ Hᵀ R⁻¹ H (r × r) and a = Σ Hᵀ R⁻¹ ν to the information of y, ν = z − H θ⁻ the
   innovations. With G = Eᵀ P⁻ E (r × r), Woodbury's identity gives the covariance form

       b = (I + J G)⁻¹ a,   M = (I + J G)⁻¹ J,
       θ = θ⁻ + P⁻E b,      P = P⁻ − P⁻E M Eᵀ P⁻,
       NIS = Σ νᵀ R⁻¹ ν − (G a)ᵀ b   ( = νᵀ S⁻¹ ν, S = H P⁻ Hᵀ + R ),

   O(D² r + r³). The m measurement components of a step overlap on the same
   coordinates (every vehicle has a GNSS row and V2F rows, a feature is seen by
   several vehicles), so r < m, and the cost is below the O(D² m + m³) of a Kalman gain
   and far below the O(D³) of the dense Joseph form. Where the rows observe more than
   half of the coordinates (GNSS of position and velocity), two inversions are cheaper:
   G⁺ = (G⁻¹ + J)⁻¹ is the posterior covariance of y, and the u = D − r coordinates no row
   observes (features out of every vehicle's range) follow by regression on y
   (`_observed_block_update`): 2 r³ + O(u r² + u² r) operations instead of the 2 D³ of
   P = (P⁻⁻¹ + E J Eᵀ)⁻¹; where u is small (≲ 4 % of D) the whole state is inverted
   (the copies into and out of the blocks cost more than they save). The inversions
   (`linalg`) are Cholesky, a triangular inverse by recursive halving with matrix
   products in place, and L⁻ᵀL⁻¹:
   LAPACK's potri, whose triangular inverse is several times slower in the OpenBLAS that
   NumPy ships, was most of a step. Where P⁻ and R are so far apart that the
   posterior of y comes out not positive definite (a small difference of huge numbers),
   the component takes the stacked-row update of the dense form instead
   (`kf_update_nis`: Joseph form, or square-root form where that fails).
   The information (J, a) of every component is formed in one pass over the step's
   rows (the components' observed coordinates laid out one after the other), so what
   is done per component is its dense algebra alone.

Cost per step: Σ over components of O(D_c² r_c + r_c³), plus O(n) for the alone
vehicles — linear in the number of vehicles while components stay small, and the
dense form's O(D³) where every entity ends up in one component (a dense city whose
vehicles share features).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from cooploc.estimators.base import birth_beliefs, checked_states
from cooploc.estimators.oracle_kf.births import feature_births
from cooploc.gaussian import (
    Gaussians,
    block_diagonal,
    kf_predict,
    kf_update_nis,
    kf_update_relative,
    spd_inverse_and_product,
    symmetrize,
)
from cooploc.types import AssociationTruth, Estimate, FloatArray, Frame, IntArray, Setup

if TYPE_CHECKING:
    from cooploc.estimators.oracle_kf.params import OracleKFParams

__all__ = ["Component", "ComponentFilter"]

GATHER_COST = 90    # operations an entry of D × D the observed block's copies cost (measured, see the update)

DENSE_SUM_RATIO = 16  # entries of Σ r_c² per entry of J below which J is summed in a dense array

VEHICLE, FEATURE, CLONE = 0, 1, 2   # CLONE: H x_{k−1} of a vehicle with an odometry row, for one step
N_KINDS = 3


@dataclass
class Component:
    """A set of coupled entities and their dense joint Gaussian.

    Attributes
    ----------
    kind : (n,) VEHICLE, FEATURE or CLONE of each entity.
    ids : (n,) the entity ids (vehicle and feature ids may overlap: `kind` tells them apart; a
        clone has its vehicle's id).
    start : (n,) index of each entity's first state component in `mean`.
    mean : (D,) stacked state.
    cov : (D, D) joint covariance.
    """

    kind: IntArray
    ids: IntArray
    start: IntArray
    mean: FloatArray
    cov: FloatArray
    _of_kind: dict[int | None, tuple[IntArray, IntArray]] = field(default_factory=dict, repr=False,
                                                                  compare=False)

    def indices(self, entities: IntArray, dim: int) -> IntArray:
        """(len(entities), dim) state indices of `entities` (positions in this component)."""
        return self.start[entities, None] + np.arange(dim)

    def of_kind(self, kind: int | None, dims: IntArray) -> tuple[IntArray, IntArray]:
        """(positions, (n, d) state indices) of the entities of `kind` (None: the vehicles and
        features, where both have one dimension), kept with the component: its entities never
        change (merging, cloning and marginalising make new ones)."""
        if kind not in self._of_kind:
            entities = np.flatnonzero(self.kind < CLONE if kind is None else self.kind == kind)
            dim = int(dims[VEHICLE if kind is None else kind])
            self._of_kind[kind] = entities, self.indices(entities, dim)
        return self._of_kind[kind]


def _offsets(sizes: IntArray) -> IntArray:
    """Where each of consecutive blocks of `sizes` starts."""
    return np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)


def _starts(kind: IntArray, dims: IntArray) -> IntArray:
    return _offsets(dims[kind])


def _singletons(kind: int, ids: IntArray, beliefs: Gaussians, dims: IntArray) -> list[Component]:
    """One component per belief of a stack (entities of one kind, uncoupled)."""
    kinds = np.array([kind])
    return [Component(kinds, ids[i:i + 1], np.zeros(1, np.int64), beliefs.mean[i].copy(),
                      beliefs.cov[i].copy()) for i in range(ids.size)]


def _select(c: Component, keep: np.ndarray, dims: IntArray) -> Component:
    """`c` with only the entities `keep` (mask): the others marginalised out."""
    from cooploc._matrix_kernels import take_block  # numba: loaded when first needed

    entities = np.flatnonzero(keep)
    lengths = dims[c.kind[entities]]
    offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    idx = np.repeat(c.start[entities] - offsets, lengths) + np.arange(lengths.sum())   # ascending
    cov = np.empty((idx.size, idx.size))
    take_block(c.cov, idx, idx, cov)
    kind = c.kind[entities]
    return Component(kind, c.ids[entities], _starts(kind, dims), c.mean[idx], cov)


def _merge(parts: Sequence[Component], dims: IntArray) -> Component:
    """One component of uncoupled `parts`: means stacked, covariances block diagonal."""
    kind = np.concatenate([p.kind for p in parts])
    D = sum(p.mean.size for p in parts)
    cov = np.zeros((D, D))
    at = 0
    for p in parts:
        cov[at:at + p.mean.size, at:at + p.mean.size] = p.cov
        at += p.mean.size
    return Component(kind, np.concatenate([p.ids for p in parts]), _starts(kind, dims),
                     np.concatenate([p.mean for p in parts]), cov)


def _with_clones(c: Component, vehicles: IntArray, H: FloatArray, dims: IntArray) -> Component:
    """`c` with the clones c_j = H x_{e_j} of its vehicles at positions `vehicles` appended
    (stochastic cloning): with c = A θ, the joint of [θ; c] has mean [θ; A θ] and covariance
    [[P, P Aᵀ], [A P, A P Aᵀ]] — the clones correlated with every entity of `c`."""
    idx = c.indices(vehicles, int(dims[VEHICLE]))                     # (n, dx)
    n, do, D = vehicles.size, H.shape[0], c.mean.size
    cross = (c.cov[:, idx] @ H.T).reshape(D, n * do)                   # P Aᵀ
    clone_cov = np.einsum("ai,nik->nak", H, cross[idx]).reshape(n * do, n * do)   # A P Aᵀ
    kind = np.concatenate([c.kind, np.full(n, CLONE)])
    return Component(kind, np.concatenate([c.ids, c.ids[vehicles]]), _starts(kind, dims),
                     np.concatenate([c.mean, (c.mean[idx] @ H.T).ravel()]),    # [θ; H x]
                     np.block([[c.cov, cross], [cross.T, symmetrize(clone_cov)]]))


def _blocks_positive_definite(cov: FloatArray, c: Component, dims: IntArray) -> bool:
    """Whether `cov` (a covariance of `c`) is finite and every vehicle's and feature's
    diagonal block of it positive definite."""
    from cooploc._matrix_kernels import all_finite, blocks_positive_definite  # numba: loaded when needed

    kinds = [None] if dims[VEHICLE] == dims[FEATURE] else [VEHICLE, FEATURE]   # one batch of blocks
    for kind in kinds:
        entities, idx = c.of_kind(kind, dims)
        if entities.size and not blocks_positive_definite(cov, np.ascontiguousarray(idx[:, 0]),
                                                          idx.shape[1]):
            return False
    return all_finite(cov)


def _full(lower: FloatArray) -> FloatArray:
    """The symmetric matrix of a Fortran-ordered lower triangle (`linalg.spd_inverse_lower`),
    in C order (its transpose: free)."""
    from cooploc._matrix_kernels import mirror_lower  # numba: loaded when first needed

    mirror_lower(lower)
    return lower.T


def _add_at(W: FloatArray, i: IntArray, j: IntArray, values: FloatArray) -> None:
    """W[i, j] += values, (i, j) distinct, for a Fortran-ordered W: through its flat view,
    a one-dimensional index (a two-dimensional one cost ≈ 4 % of a step of many small
    components)."""
    flat = W.T.reshape(-1)          # C-ordered Wᵀ: a view, entry (i, j) of W at j·n + i
    if not np.may_share_memory(flat, W):     # a copy: W was not Fortran-ordered
        raise AssertionError("W must be Fortran-ordered")
    flat[j * W.shape[0] + i] += values


def _observed_block_update(P: FloatArray, E: IntArray, nonzero: IntArray, values: FloatArray,
                           a: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """(posterior covariance, mean shift) by adding the information to the inverse of the
    observed block: y = Eᵀθ, the rest u of the state regressed on y.

    With G = Eᵀ P⁻ E the prior covariance of y, the posterior of y is
    G⁺ = (G⁻¹ + J)⁻¹ and its mean y⁻ + G⁺ a; the unobserved u = A y + e with
    A = P⁻_uy G⁻¹ and e independent of y and of the rows, so P⁺_uy = A G⁺,
    P⁺_uu = P⁻_uu − A (G − G⁺) Aᵀ and u moves by A G⁺ a. G⁻¹ itself is not needed:
    (G⁻¹ + J) G⁺ = I gives G⁻¹ G⁺ = I − J G⁺, so with B = P⁻_uy J (J has few entries)

        P⁺_uy = P⁻_uy − B G⁺,   P⁺_uu = P⁻_uu − B P⁺_yu   (A (G − G⁺) = B G⁺),
        A G⁺ a = P⁻_uy (a − J G⁺ a).

    Two r × r inversions (`linalg.spd_inverse_lower`) and 2 u r² + 2 u² r operations,
    instead of the two D × D inversions of P = (P⁻⁻¹ + E J Eᵀ)⁻¹ over the whole state
    (the form with A took one more u × r × r product, and a copy of G⁻¹).
    The blocks are copied out of P⁻ and the posterior into place by compiled loops over
    runs of consecutive indices (`_matrix_kernels`). P⁺_uy is a difference that cancels
    where the rows know y far better than the prior did; against the dense filter the
    posterior stays within 1e-9 of each belief's scale (≤ 4e-10 measured on
    sumo-braunschweig-tlr; `benchmarks/oracle_kf.py`, docs/oracle_kf.md).

    J (r × r) is given by the entries the rows reach, `values` at flat indices `nonzero`
    (the rows couple few pairs; every other entry is zero), and only they are added.
    None if round-off leaves G or G⁻¹ + J not positive definite.
    """
    from cooploc._matrix_kernels import place_partition, sparse_product, take_block, take_lower
    from cooploc.estimators.oracle_kf.linalg import spd_inverse_lower

    D, r = P.shape[0], E.size
    u = D - r
    # the regression of u costs O(u r²) and copies of the D × D matrix into and out of
    # the blocks (≈ GATHER_COST operations an entry); where u is small, inverting the
    # whole state (y = θ, J zero where no row observes) is cheaper: at D = 612 the two
    # took the same time at u ≈ 24
    whole = 2 * D**3 <= 2 * r**3 + 2 * u * r * r + 2 * u * u * r + GATHER_COST * D * D
    i, j = np.divmod(nonzero, r)
    lower = i >= j   # only these are added: the upper triangles are never read (G's is never written)
    if whole:   # y = θ: J's nonzeros and a placed on every coordinate (zero where unobserved)
        G_inv = spd_inverse_lower(P.T)                     # symmetric: Pᵀ is P, Fortran-ordered
        if G_inv is None:
            return None
        _add_at(G_inv, E[i[lower]], E[j[lower]], values[lower])   # P⁻⁻¹ + J, lower triangle
        post = spd_inverse_lower(G_inv, overwrite=True)
        if post is None:
            return None
        post = _full(post)
        return post, post @ np.bincount(E, a, minlength=D)
    G = np.empty((r, r), order="F")
    take_lower(P, E, G)                                    # G = Eᵀ P⁻ E, lower triangle
    info = spd_inverse_lower(G, overwrite=True)
    if info is None:
        return None
    _add_at(info, i[lower], j[lower], values[lower])       # G⁻¹ + J, lower triangle
    post_y = spd_inverse_lower(info, overwrite=True)
    if post_y is None:
        return None
    post_y = _full(post_y)                                 # G⁺
    shift_y = post_y @ a                                   # G⁺ a
    unobserved = np.ones(D, dtype=bool)
    unobserved[E] = False
    u = np.flatnonzero(unobserved)
    P_uy, P_uu = np.empty((u.size, r)), np.empty((u.size, u.size))
    take_block(P, u, E, P_uy)
    take_block(P, u, u, P_uu)
    B = sparse_product(P_uy, i, j, values)                 # P⁻_uy J
    post_uy = P_uy - B @ post_y                            # P⁺_uy = P⁻_uy − B G⁺
    P_uu -= B @ post_uy.T                                  # P⁺_uu = P⁻_uu − B P⁺_yu
    post = np.empty((D, D))
    place_partition(post, E, u, post_y, post_uy, symmetrize(P_uu))
    shift = np.empty(D)
    shift[E] = shift_y
    shift[u] = P_uy @ (a - np.bincount(i, values * shift_y[j], minlength=r))   # A G⁺ a = P⁻_uy (a − J G⁺ a)
    return post, shift


@dataclass(frozen=True)
class _Rows:
    """Rows of one sensor of one step for one component: z_i = Σ_t H_t θ_{e_t(i)} + w_i.

    z (n, dz), R (n, dz, dz); terms: per entity the row involves, the positions of
    the entities in the component (n,), the observation block H_t (dz, d_t) and the
    entities' kind.
    """

    z: FloatArray
    R: FloatArray
    terms: tuple[tuple[IntArray, FloatArray, int], ...]

    def take(self, rows: IntArray) -> _Rows:
        return _Rows(self.z[rows], self.R[rows], tuple((e[rows], H, kind) for e, H, kind in self.terms))


class ComponentFilter:
    """`oracle-kf` in component form (module docstring)."""

    def __init__(self, setup: Setup, params: OracleKFParams, truth: AssociationTruth) -> None:
        self.name = "oracle-kf"
        self.setup, self.params, self.truth = setup, params, truth
        dx = setup.vehicle_layout.dim
        df = setup.feature_layout.dim if setup.feature_layout is not None else 0
        odometry = setup.sensors.get("odometry")
        self.Ho = None if odometry is None else odometry.observation_matrix(dx)
        do = 0 if self.Ho is None else self.Ho.shape[0]
        self.dims = np.array([dx, df, do])
        self.motion = (setup.vehicle_motion, setup.feature_motion)
        self.F = tuple(m.transition_matrix(setup.dt) if m is not None else None for m in self.motion)
        self._F_blocks = np.zeros((N_KINDS, self.dims.max(), self.dims.max()))   # per kind, zero padded
        for kind, F in enumerate(self.F):
            if F is not None and self.dims[kind]:
                self._F_blocks[kind, :F.shape[0], :F.shape[1]] = F
        self._F_blocks[CLONE, :do, :do] = np.eye(do)                   # a clone is static
        self.Hg = (setup.sensors["gnss"].observation_matrix(dx) if "gnss" in setup.sensors else None)
        v2f = setup.sensors.get("v2f")
        self.Hx = v2f.observation_matrix(dx) if v2f is not None and df else None
        self.Hf = v2f.observation_matrix(df) if v2f is not None and df else None
        # the state components any row observes, per kind: the coordinates y of the update
        used = [np.zeros(dx, bool), np.zeros(df, bool), np.ones(do, bool)]   # a clone: all of it
        for kind, H in ((VEHICLE, self.Hg), (VEHICLE, self.Hx), (FEATURE, self.Hf), (VEHICLE, self.Ho)):
            if H is not None:
                used[kind] |= (H != 0).any(axis=0)
        self.observed_cols = tuple(np.flatnonzero(u) for u in used)

        self.alone_ids: IntArray = np.zeros(0, dtype=np.int64)
        self.alone = Gaussians(np.zeros((0, dx)), np.zeros((0, dx, dx)))
        self.components: list[Component] = []
        self.feature_ids: IntArray = np.zeros(0, dtype=np.int64)
        self.last_seen: IntArray = np.zeros(0, dtype=np.int64)
        self._lookup: tuple[IntArray, IntArray, IntArray] | None = None
        self._present: IntArray | None = None   # the vehicles of the previous step
        self._Q: list[FloatArray | None] = [None, None]   # Q of a model whose noise is constant
        self._cloned: IntArray = np.zeros(0, dtype=np.int64)   # this step's vehicles with clones
        self._previous: tuple[IntArray, Gaussians] | None = None   # alone cloned vehicles at k − 1

    # -- one step -------------------------------------------------------------------

    def step(self, frame: Frame) -> Estimate:
        k = frame.k
        present = frame.vehicles
        self._forget(present, k)
        self._clone(frame)
        self._predict()
        self._enter(frame, present)
        origin = self.truth.origin[k].get("v2f")
        v2f = frame.batches.get("v2f")
        rows = np.zeros(0, dtype=np.int64)
        if v2f is not None and len(v2f) and self.dims[FEATURE] and origin is not None:
            rows = np.flatnonzero((origin >= 0) & np.isin(v2f.sensor, present))
        gnss = frame.batches.get("gnss")
        gnss_rows = np.zeros(0, dtype=np.int64)
        if gnss is not None and len(gnss) and self.Hg is not None:
            gnss_rows = np.flatnonzero(np.isin(gnss.subject, present))
        if rows.size:
            self._first_seen(frame, rows, origin[rows], k)
            self._couple(v2f.sensor[rows], origin[rows],
                         gnss.subject[gnss_rows] if gnss_rows.size else gnss_rows)
        nis = self._update(frame, gnss_rows, rows, origin)
        self._drop_clones()
        return self._estimate(nis)

    def _forget(self, present: IntArray, k: int) -> None:
        """Marginalise out the vehicles that left and the features unseen for too long."""
        fresh = k - self.last_seen <= self.params.feature_timeout
        if fresh.all() and np.array_equal(present, self._present):
            return  # the usual step: the same vehicles, no feature timed out
        self._lookup, self._present = None, present
        stale = self.feature_ids[~fresh]
        self.feature_ids, self.last_seen = self.feature_ids[fresh], self.last_seen[fresh]
        stay = np.isin(self.alone_ids, present)
        if not stay.all():
            self.alone_ids, self.alone = self.alone_ids[stay], self.alone.take(stay)
        kept = []
        for c in self.components:
            keep = np.where(c.kind == VEHICLE, np.isin(c.ids, present), ~np.isin(c.ids, stale))
            if keep.all():
                kept.append(c)
            elif keep.any():
                kept.append(_select(c, keep, self.dims))
        self.components = kept

    def _clone(self, frame: Frame) -> None:
        """Stochastic cloning of H x_{k−1}, before the prediction, for every vehicle in the state
        (so present at k − 1 and at k) with an odometry row: a vehicle of a component gets its
        clone in the component (`_with_clones`); an alone vehicle with one row keeps its belief
        at k − 1 for `kf_update_relative`, one with several rows becomes a component first."""
        self._cloned, self._previous = np.zeros(0, dtype=np.int64), None
        odometry = frame.batches.get("odometry")
        if self.Ho is None or odometry is None or not len(odometry):
            return
        subjects, counts = np.unique(odometry.subject, return_counts=True)
        several = np.isin(self.alone_ids, subjects[counts > 1])
        if several.any():
            self.components += _singletons(VEHICLE, self.alone_ids[several], self.alone.take(several),
                                           self.dims)
            self.alone_ids, self.alone = self.alone_ids[~several], self.alone.take(~several)
            self._lookup = None
        keys, comp, pos = self._table()
        if not keys.size:
            return
        at = np.minimum(np.searchsorted(keys, subjects * N_KINDS + VEHICLE), keys.size - 1)
        known = keys[at] == subjects * N_KINDS + VEHICLE
        self._cloned = subjects[known]
        if not self._cloned.size:
            return
        comp, pos = comp[at[known]], pos[at[known]]
        alone = comp < 0
        if alone.any():
            self._previous = (self._cloned[alone], self.alone.take(pos[alone]))
        order = np.argsort(comp, kind="stable")
        comp, pos = comp[order], pos[order]
        starts = np.flatnonzero(np.r_[True, np.diff(comp) != 0])
        for first, end in zip(starts.tolist(), np.r_[starts[1:], comp.size].tolist(), strict=True):
            i = int(comp[first])
            if i >= 0:   # the vehicles of component i
                self.components[i] = _with_clones(self.components[i], pos[first:end], self.Ho, self.dims)
        self._lookup = None

    def _drop_clones(self) -> None:
        """Marginalise the clones out once the odometry rows are fused."""
        if not self._cloned.size:
            return
        self.components = [_select(c, c.kind != CLONE, self.dims) if (c.kind == CLONE).any() else c
                           for c in self.components]
        self._cloned, self._previous, self._lookup = np.zeros(0, dtype=np.int64), None, None

    def _predict(self) -> None:
        """θ⁻ = F θ, P⁻ = F P Fᵀ + Q, block by block (F and Q are block diagonal)."""
        if len(self.alone):
            self.alone = kf_predict(self.alone, self.F[VEHICLE], self._noise(VEHICLE, self.alone.mean))
        if not self.components:
            return
        noise = [self._component_noise(kind) for kind in (VEHICLE, FEATURE)]
        for c, Q_vehicles, Q_features in zip(self.components, *noise, strict=True):
            self._predict_component(c, (Q_vehicles, Q_features))

    def _noise(self, kind: int, means: FloatArray) -> FloatArray:
        """Q of entities of `kind` with `means` (n, d): (d, d), or (n, d, d) where it turns with them."""
        model = self.motion[kind]
        if getattr(model, "state_dependent_noise", True):
            return model.noise_covariance(self.setup.dt, means)
        if self._Q[kind] is None:
            self._Q[kind] = model.noise_covariance(self.setup.dt)
        return self._Q[kind]

    def _component_noise(self, kind: int) -> list[FloatArray | None]:
        """Per component, Q of its entities of `kind` (`_noise`), from θ, not θ⁻; one call of
        the motion model for the entities of every component."""
        if self.motion[kind] is None or not self.dims[kind]:
            return [None] * len(self.components)
        means = [c.mean[c.of_kind(kind, self.dims)[1]] for c in self.components]
        Q = self._noise(kind, np.concatenate(means))
        if Q.ndim == 2:
            return [Q] * len(self.components)
        return np.split(Q, np.cumsum([m.shape[0] for m in means])[:-1])

    def _predict_component(self, c: Component, noise: tuple[FloatArray | None, FloatArray | None]) -> None:
        from cooploc._matrix_kernels import congruence_blocks  # numba: loaded when first needed

        new_mean = c.mean.copy()
        cov = np.empty_like(c.cov)
        congruence_blocks(c.cov, c.start, self.dims[c.kind], self._F_blocks[c.kind], cov)   # F P Fᵀ
        for kind in (VEHICLE, FEATURE):
            entities, idx = c.of_kind(kind, self.dims)                                  # (n, d)
            if entities.size:
                new_mean[idx] = c.mean[idx] @ self.F[kind].T
                cov[idx[:, :, None], idx[:, None, :]] += symmetrize(noise[kind])        # stays symmetric
        c.mean, c.cov = new_mean, cov

    def _enter(self, frame: Frame, present: IntArray) -> None:
        """Entering vehicles join the alone ones, at their prior or first fix."""
        in_state = np.concatenate([self.alone_ids, *[c.ids[c.kind == VEHICLE] for c in self.components]])
        new = np.setdiff1d(present, in_state)
        if not new.size:
            return
        born = birth_beliefs(self.setup, new, frame)
        self._lookup = None
        ids = np.concatenate([self.alone_ids, new])
        order = np.argsort(ids, kind="stable")
        self.alone_ids = ids[order]
        self.alone = Gaussians(np.concatenate([self.alone.mean, born.mean])[order],
                               np.concatenate([self.alone.cov, born.cov])[order])

    def _first_seen(self, frame: Frame, rows: IntArray, origin: IntArray, k: int) -> None:
        """Features seen for the first time become components of their own (`births`)."""
        new = np.setdiff1d(origin, self.feature_ids)
        if not new.size:
            return
        first = np.unique(origin, return_index=True)[1]
        first = first[np.isin(origin[first], new)]                    # the first row of each, in id order
        sensor_means = self._vehicle_means(frame.batches["v2f"].sensor[rows[first]])
        born = feature_births(self.setup, frame, new, rows[first], sensor_means)
        self.components += _singletons(FEATURE, new, born, self.dims)
        self._lookup = None
        ids = np.concatenate([self.feature_ids, new])
        order = np.argsort(ids, kind="stable")
        self.feature_ids = ids[order]
        self.last_seen = np.concatenate([self.last_seen, np.full(new.size, k)])[order]

    def _couple(self, sensors: IntArray, features: IntArray, gnss_subjects: IntArray) -> None:
        """Merge the components that V2F rows (sensor, feature) link.

        Alone vehicles that sense a feature, or that have more than one GNSS row (the
        batch update takes one row per vehicle), become components first (`_promote`).
        """
        subjects, counts = np.unique(gnss_subjects, return_counts=True)
        promote = np.isin(self.alone_ids, sensors) | np.isin(self.alone_ids, subjects[counts > 1])
        if promote.any():
            self._promote(promote)
        comp_v, _ = self._locate(VEHICLE, sensors)
        comp_f, _ = self._locate(FEATURE, features)
        links = np.unique(np.stack([comp_v, comp_f], axis=1)[comp_v != comp_f], axis=0)
        if not links.size:
            return  # the usual step: every row inside a component
        parent = list(range(len(self.components)))  # union–find over the components

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = i = parent[parent[i]]
            return i

        for u, v in links.tolist():
            ru, rv = root(u), root(v)
            parent[max(ru, rv)] = min(ru, rv)
        groups: dict[int, list[Component]] = {}
        for i, c in enumerate(self.components):
            groups.setdefault(root(i), []).append(c)
        self._lookup = None
        self.components = [parts[0] if len(parts) == 1 else _merge(parts, self.dims)
                           for parts in groups.values()]

    def _promote(self, promote: np.ndarray) -> None:
        """The alone vehicles `promote` (mask) become components of their own; one with a
        clone (`_previous`: its belief N(m, P) at k − 1) takes it along, the joint of
        [x_k; H x_{k−1}] with Cov(x_k, H x_{k−1}) = F P Hᵀ."""
        ids, beliefs = self.alone_ids[promote], self.alone.take(promote)
        self.alone_ids, self.alone = self.alone_ids[~promote], self.alone.take(~promote)
        self._lookup = None
        cloned = np.zeros(ids.size, bool)
        if self._previous is not None:
            previous_ids, previous = self._previous
            cloned = np.isin(ids, previous_ids)
        self.components += _singletons(VEHICLE, ids[~cloned], beliefs.take(~cloned), self.dims)
        if not cloned.any():
            return
        previous = previous.take(np.searchsorted(previous_ids, ids[cloned]))
        H, F, dx = self.Ho, self.F[VEHICLE], int(self.dims[VEHICLE])
        predicted = beliefs.take(cloned)
        cross = F @ previous.cov @ H.T                                   # Cov(x_k, H x_{k−1})
        clone_cov = symmetrize(H @ previous.cov @ H.T)
        kind = np.array([VEHICLE, CLONE])
        for i, vehicle in enumerate(ids[cloned].tolist()):
            self.components.append(Component(
                kind, np.array([vehicle, vehicle]), np.array([0, dx]),
                np.concatenate([predicted.mean[i], H @ previous.mean[i]]),
                np.block([[predicted.cov[i], cross[i]], [cross[i].T, clone_cov[i]]])))

    # -- lookup -----------------------------------------------------------------------

    def _table(self) -> tuple[IntArray, IntArray, IntArray]:
        """Every entity's key (N_KINDS id + kind), component (−1: alone) and position, sorted by key
        (kept until the membership changes: `_lookup = None`)."""
        if self._lookup is None:
            self._lookup = self._build_table()
        return self._lookup

    def _build_table(self) -> tuple[IntArray, IntArray, IntArray]:
        keys = [self.alone_ids * N_KINDS + VEHICLE] + [c.ids * N_KINDS + c.kind for c in self.components]
        comp = [np.full(self.alone_ids.size, -1)] + [np.full(c.ids.size, i)
                                                    for i, c in enumerate(self.components)]
        pos = [np.arange(self.alone_ids.size)] + [np.arange(c.ids.size) for c in self.components]
        keys_all = np.concatenate(keys)
        order = np.argsort(keys_all, kind="stable")
        return keys_all[order], np.concatenate(comp)[order], np.concatenate(pos)[order]

    def _locate(self, kind: int, ids: IntArray) -> tuple[IntArray, IntArray]:
        """(component (−1: alone), position in it) of entities `ids` of `kind`."""
        keys, comp, pos = self._table()
        at = np.searchsorted(keys, ids * N_KINDS + kind)
        return comp[at], pos[at]

    def _vehicle_means(self, ids: IntArray) -> FloatArray:
        """(n, dx) current means of vehicles `ids`."""
        dx = int(self.dims[VEHICLE])
        comp, pos = self._locate(VEHICLE, ids)
        means = np.empty((ids.size, dx))
        alone = comp < 0
        means[alone] = self.alone.mean[pos[alone]]
        for i in np.flatnonzero(~alone):
            c = self.components[comp[i]]
            means[i] = c.mean[c.start[pos[i]]:c.start[pos[i]] + dx]
        return means

    # -- update ---------------------------------------------------------------------

    def _update(self, frame: Frame, gnss_rows: IntArray, v2f_rows: IntArray,
                origin: IntArray | None) -> tuple[float, int]:
        """Update the alone vehicles in one batch and each component with its rows; (NIS, dof)."""
        nis, dof = 0.0, 0
        sensors: list[tuple[IntArray, _Rows]] = []   # per sensor: each row's component, the rows
        odometry = frame.batches.get("odometry")
        if self._cloned.size:   # z = H x_k − H x_{k−1} + w (Gulati eq. 4): alone vehicles
            # first, before their GNSS rows change Cov(x_k, x_{k−1}) = F P
            rows = np.flatnonzero(np.isin(odometry.subject, self._cloned))
            comp, pos = self._locate(VEHICLE, odometry.subject[rows])
            alone = comp < 0
            if alone.any():
                n, d = self._update_alone_odometry(odometry.subject[rows[alone]], pos[alone],
                                                   odometry.z[rows[alone]], odometry.cov[rows[alone]])
                nis, dof = nis + n, dof + d
            coupled = rows[~alone]
            if coupled.size:
                _, pos_clone = self._locate(CLONE, odometry.subject[coupled])
                do = self.Ho.shape[0]
                terms = ((pos[~alone], self.Ho, VEHICLE), (pos_clone, -np.eye(do), CLONE))
                sensors.append((comp[~alone], _Rows(odometry.z[coupled], odometry.cov[coupled], terms)))
        if gnss_rows.size:
            gnss = frame.batches["gnss"]
            comp, pos = self._locate(VEHICLE, gnss.subject[gnss_rows])
            z, R = gnss.z[gnss_rows], gnss.cov[gnss_rows]
            alone = comp < 0
            if alone.any():
                n, d = self._update_alone(pos[alone], z[alone], R[alone])
                nis, dof = nis + n, dof + d
            coupled = np.flatnonzero(~alone)
            if coupled.size:
                sensors.append((comp[coupled], _Rows(z, R, ((pos, self.Hg, VEHICLE),)).take(coupled)))
        if v2f_rows.size:
            v2f = frame.batches["v2f"]
            features = origin[v2f_rows]
            self.last_seen[np.searchsorted(self.feature_ids, features)] = frame.k
            comp, pos_v = self._locate(VEHICLE, v2f.sensor[v2f_rows])   # never alone (`_couple`)
            _, pos_f = self._locate(FEATURE, features)
            terms = ((pos_f, self.Hf, FEATURE), (pos_v, -self.Hx, VEHICLE))          # z = H f − H x + w
            sensors.append((comp, _Rows(v2f.z[v2f_rows], v2f.cov[v2f_rows], terms)))
        if sensors:
            n, d = self._update_components(sensors)
            nis, dof = nis + n, dof + d
        return nis, dof

    def _update_alone_odometry(self, ids: IntArray, pos: IntArray, z: FloatArray, R: FloatArray
                               ) -> tuple[float, int]:
        """Stochastic-cloning update (`kf_update_relative`) of the alone vehicles `ids` at `pos`
        with one odometry row each, from their beliefs at k − 1 (`_previous`)."""
        previous_ids, previous = self._previous
        post, nis, _ = kf_update_relative(previous.take(np.searchsorted(previous_ids, ids)),
                                          self.alone.take(pos), self.F[VEHICLE], z, self.Ho, R)
        mean, cov = self.alone.mean.copy(), self.alone.cov.copy()
        mean[pos], cov[pos] = post.mean, post.cov
        self.alone = Gaussians(mean, cov)
        return float(nis.sum()), int(z.size)

    def _update_alone(self, pos: IntArray, z: FloatArray, R: FloatArray) -> tuple[float, int]:
        """Joseph-form update of the alone vehicles at `pos`, one GNSS row each."""
        post, nis = kf_update_nis(self.alone.take(pos), z, self.Hg, R)
        mean, cov = self.alone.mean.copy(), self.alone.cov.copy()
        mean[pos], cov[pos] = post.mean, post.cov
        self.alone = Gaussians(mean, cov)
        return float(nis.sum()), int(z.size)

    def _update_components(self, sensors: list[tuple[IntArray, _Rows]]) -> tuple[float, int]:
        """Update every component that has rows (module docstring, step 5); (NIS, dof).

        The information of the rows, (J, a, Σ νᵀR⁻¹ν) of each component on its observed
        coordinates y = Eᵀθ, is computed for the rows of all components at once: the
        components' entities are numbered in one sequence, their observed coordinates laid
        out one component after the other in one y, and each row's terms scattered into
        its component's J (indexed as r_c × r_c blocks one after the other; only the entries
        that rows reach are summed and kept) and a.
        """
        from cooploc._matrix_kernels import sum_duplicates  # numba: loaded when first needed

        comps = self.components
        n = len(comps)
        n_entities = np.array([c.ids.size for c in comps])
        entity_at = _offsets(n_entities)                          # first entity of each component
        state_at = _offsets(np.array([c.mean.size for c in comps]))
        kind = np.concatenate([c.kind for c in comps])
        start = np.concatenate([c.start for c in comps]) + np.repeat(state_at, n_entities)
        owner = np.repeat(np.arange(n), n_entities)
        terms = [[(entity_at[comp] + e, H, k) for e, H, k in rows.terms] for comp, rows in sensors]

        observed = np.unique(np.concatenate([e for t in terms for e, _, _ in t]))
        widths = np.array([cols.size for cols in self.observed_cols])[kind[observed]]
        slot = np.full(kind.size, -1)
        slot[observed] = _offsets(widths)                         # each observed entity's place in y
        E = np.empty(int(widths.sum()), dtype=np.int64)           # ascending within each component
        for k, cols in enumerate(self.observed_cols):
            entities = observed[kind[observed] == k]
            if entities.size:
                at = (slot[entities, None] + np.arange(cols.size)).ravel()
                E[at] = (start[entities, None] + cols).ravel()
        y = np.concatenate([c.mean for c in comps])[E]
        r = np.bincount(owner[observed], widths, minlength=n).astype(np.int64)
        y_at, J_at = _offsets(r), _offsets(r * r)
        # J entry (u, t) of y, both in component c: J_at[c] + (u − y_at[c]) r[c] + (t − y_at[c])
        J_base = J_at - y_at * (r + 1)

        J_idx, J_val, a_idx, a_val = [], [], [], []
        nu_R_nu, dof = np.zeros(n), np.zeros(n, dtype=np.int64)
        for (comp, rows), t in zip(sensors, terms, strict=True):
            blocks = []
            for e, H, k in t:
                Hc = H[:, self.observed_cols[k]]                                 # H on y
                blocks.append((slot[e, None] + np.arange(Hc.shape[1]), Hc))      # (rows, w) places in y
            nu = rows.z - sum(y[idx] @ Hc.T for idx, Hc in blocks)                # ν = z − H θ⁻
            R_inv, R_nu = spd_inverse_and_product(rows.R, nu)                    # R⁻¹ (information), R⁻¹ ν
            nu_R_nu += np.bincount(comp, np.sum(nu * R_nu, axis=1), minlength=n)
            dof += np.bincount(comp, minlength=n) * rows.z.shape[1]
            base, scale = J_base[comp][:, None, None], r[comp][:, None, None]
            for idx_t, H_t in blocks:
                a_idx.append(idx_t.ravel())
                a_val.append((R_nu @ H_t).ravel())                               # Hᵀ R⁻¹ ν
                R_H = R_inv @ H_t                                                # R⁻¹ H_t
                for idx_u, H_u in blocks:
                    J_idx.append((base + idx_u[:, :, None] * scale + idx_t[:, None, :]).ravel())
                    J_val.append((H_u.T @ R_H).ravel())                          # H_uᵀ R⁻¹ H_t
        # J's entries summed over the rows where they are (a few per coordinate), in the
        # rows' order, as a dense Σ r_c² array would hold them: through such an array where
        # it is not much larger than the entries (one large component), else by sorting
        # (many small components: the array would be mostly zeros); the same sums either way
        J_idx, J_val, size = np.concatenate(J_idx), np.concatenate(J_val), int((r * r).sum())
        if size <= DENSE_SUM_RATIO * J_idx.size:
            nonzero, J_values = sum_duplicates(J_idx, J_val, size)
        else:
            nonzero, inverse = np.unique(J_idx, return_inverse=True)
            J_values = np.bincount(inverse, J_val, minlength=nonzero.size)
        a_all = np.bincount(np.concatenate(a_idx), np.concatenate(a_val), minlength=E.size)
        nonzero_at = np.searchsorted(nonzero, np.append(J_at, int((r * r).sum())))

        nis, total_dof = 0.0, 0
        for i in np.flatnonzero(r).tolist():
            y_part = slice(y_at[i], y_at[i] + r[i])
            part = slice(nonzero_at[i], nonzero_at[i + 1])
            reduction = self._update_component(comps[i], nonzero[part] - J_at[i], J_values[part],
                                               a_all[y_part], E[y_part] - state_at[i])
            if reduction is not None:
                nis += float(nu_R_nu[i]) - reduction                    # νᵀ S⁻¹ ν, Woodbury
            else:  # P⁻ ≫ R: round-off ate the posterior; the stacked rows of the dense form
                nis += self._update_component_rows(
                    comps[i], [rows.take(np.flatnonzero(comp == i)) for comp, rows in sensors])
            total_dof += int(dof[i])
        return nis, total_dof

    def _update_component(self, c: Component, J_nonzero: IntArray, J_values: FloatArray, a: FloatArray,
                          E: IntArray) -> float | None:
        """The information-form update of one component (module docstring, step 5), J given
        by the entries the rows reach (`J_values` at flat indices `J_nonzero`, the rest
        zero); returns (G a)ᵀ b, what the NIS is below Σ νᵀR⁻¹ν, or None (`c` untouched)
        where round-off ate the posterior."""
        P = c.cov
        r = E.size
        if 2 * r > P.shape[0]:  # most coordinates observed: two r × r inversions are cheaper
            update = _observed_block_update(P, E, J_nonzero, J_values, a)
            if update is None or not _blocks_positive_definite(update[0], c, self.dims):
                return None
            c.cov, shift = update
            c.mean = c.mean + shift                                    # θ = θ⁻ + P⁻E b
            return float(a @ shift[E])                                 # aᵀ G⁺ a = (G a)ᵀ b
        J = np.zeros(r * r)
        J[J_nonzero] = J_values
        J = J.reshape(r, r)
        PE = P[:, E]                                                   # P⁻ E   (D, r)
        G = PE[E]                                                      # Eᵀ P⁻ E
        X = np.linalg.solve(np.eye(r) + J @ G, np.column_stack([a, J]))
        b, M = X[:, 0], symmetrize(X[:, 1:])                           # (I + J G)⁻¹ [a, J]
        cov = symmetrize(P - (PE @ M) @ PE.T)                          # P = P⁻ − P⁻E M Eᵀ P⁻
        if not _blocks_positive_definite(cov, c, self.dims):
            return None
        c.mean = c.mean + PE @ b                                       # θ = θ⁻ + P⁻E b
        c.cov = cov
        return float((G @ a) @ b)

    def _update_component_rows(self, c: Component, groups: list[_Rows]) -> float:
        """The dense form's update of one component: every row stacked, `kf_update_nis`; its NIS."""
        D = c.mean.size
        H_rows, z_rows, R_blocks = [], [], []
        for g in groups:
            n, dz = g.z.shape
            H = np.zeros((n, dz, D))
            for e, H_t, _ in g.terms:
                cols = c.start[e, None] + np.arange(H_t.shape[1])                 # (n, d)
                H[np.arange(n)[:, None, None], np.arange(dz)[None, :, None], cols[:, None, :]] = H_t
            H_rows.append(H.reshape(-1, D))
            z_rows.append(g.z.ravel())
            R_blocks.append(g.R)
        z = np.concatenate(z_rows)
        post, nis = kf_update_nis(Gaussians(c.mean[None], c.cov[None]), z[None],
                                  np.concatenate(H_rows), block_diagonal(*R_blocks))
        c.mean, c.cov = post.mean[0], post.cov[0]
        return float(nis[0])

    # -- estimate -------------------------------------------------------------------

    def _estimate(self, nis: tuple[float, int]) -> Estimate:
        parts: list[list[tuple[IntArray, FloatArray, FloatArray]]] = [[], []]
        parts[VEHICLE].append((self.alone_ids, self.alone.mean, self.alone.cov))
        for c in self.components:
            for kind in (VEHICLE, FEATURE):
                entities, idx = c.of_kind(kind, self.dims)
                if entities.size:
                    cov = c.cov[idx[:, :, None], idx[:, None, :]]
                    parts[kind].append((c.ids[entities], c.mean[idx], cov))
        states = []
        for kind, label in ((VEHICLE, "vehicle"), (FEATURE, "feature")):
            d = int(self.dims[kind])
            ids = np.concatenate([p[0] for p in parts[kind]] + [np.zeros(0, np.int64)])
            mean = np.concatenate([p[1] for p in parts[kind]] + [np.zeros((0, d))])
            cov = np.concatenate([p[2] for p in parts[kind]] + [np.zeros((0, d, d))])
            order = np.argsort(ids, kind="stable")
            states.append(checked_states(self.name, label, ids[order], mean[order], cov[order]))
        features = states[FEATURE] if self.dims[FEATURE] else None
        state_dim = self.alone.mean.size + sum(c.mean.size for c in self.components)
        return Estimate(states[VEHICLE], features, {"state_dim": int(state_dim), "nis": nis})
