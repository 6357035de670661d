"""`validate_recording`: does a `Recording` mean what it says? (DESIGN §9)

The containers of `cooploc.types` check structure (shapes, finite values, SPD
covariances, unique ids). A recording can pass all of that and still be impossible:
a GNSS fix of a vehicle that does not exist, a batch of a kind no sensor of the setup
produces, frames 0.5 s apart under ``dt = 7``. Every estimator and `metrics.evaluate`
assume these rules; a recording that breaks one is refused here with an
`InvalidInputError` naming the field, the step and the value:

1. ``setup.dt`` is a positive number (not a bool or a string), ``setup.n_steps`` an
   integer (not a bool) equal to the number of frames.
2. Frame times strictly increase, ``dt`` apart (relative tolerance `DT_RTOL`).
3. Every batch kind is declared in ``setup.sensors``; its dz equals the sensor model's
   dimension (where the model states one) and is the same at every step.
4. Vehicle, feature and infrastructure ids are disjoint sets.
5. Each row's ``sensor`` is −1, a vehicle of that step's frame (``Frame.vehicles``), or
   an infrastructure sensor id; its ``subject`` is −1, a vehicle of the frame, or a
   feature.
6. Each row's truth ``origin`` is −1 (clutter), a vehicle present at that step, or a
   feature.
7. Prior ids are ids of the truth's vehicles (features, when the truth has features).
8. The truth's state dimensions equal the layouts' (features: when there are any), and
   there is one sensor pose per infrastructure id.

"A feature" is an id of the truth's features or of ``setup.feature_prior``; a
recording whose truth has no features at all (allowed: feature truth not recorded)
accepts any other id that is neither a vehicle nor an infrastructure sensor.

`load_recording` runs this on every folder and names the file and column; users who
build a `Recording` in Python call it themselves: ``validate_recording(recording)``.
The checks are vectorised over rows (one pass over the frames to gather them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.types import IntArray, Recording, lookup_ids

__all__ = ["DT_RTOL", "validate_recording"]

#: relative tolerance of frame-time steps against setup.dt (times written as decimals,
#: or summed step by step, drift by far less)
DT_RTOL = 1e-6


@dataclass(frozen=True)
class _Where:
    """One field, as a Python user and as a file reader know it."""

    attribute: str  # e.g. "frames[k].batches[kind].subject"
    file: str       # e.g. "measurements.parquet: column 'subject'"


_DT = _Where("setup.dt", "setup.json: field 'dt'")
_N_STEPS = _Where("setup.n_steps", "setup.json: field 'n_steps'")
_TIME = _Where("frames[k].t", "frames.parquet: column 't'")
_KIND = _Where("frames[k].batches", "frames.parquet: column 'batch_kinds'")
_DIM = _Where("frames[k].batches[kind].z", "frames.parquet: column 'batch_dims'")
_SENSOR = _Where("frames[k].batches[kind].sensor", "measurements.parquet: column 'sensor'")
_SUBJECT = _Where("frames[k].batches[kind].subject", "measurements.parquet: column 'subject'")
_ORIGIN = _Where("truth.origin[k][kind]", "measurements.parquet: column 'origin'")
_VEHICLE_PRIOR = _Where("setup.vehicle_prior.ids", "setup.json: field 'vehicle_prior.ids'")
_FEATURE_PRIOR = _Where("setup.feature_prior.ids", "setup.json: field 'feature_prior.ids'")
_INFRASTRUCTURE = _Where("setup.infrastructure_ids", "setup.json: field 'infrastructure_ids'")
_POSES = _Where("truth.sensor_poses", "sensor_poses.parquet")
_VEHICLE_STATES = _Where("truth.vehicle_states", "truth_vehicles.parquet: columns x_0 …")
_FEATURE_STATES = _Where("truth.feature_states", "truth_features.parquet: columns x_0 …")


class _Checker:
    def __init__(self, recording: Recording, files: bool) -> None:
        self.recording = recording
        self.files = files
        setup, truth = recording.setup, recording.truth
        self.infrastructure = np.asarray(setup.infrastructure_ids, dtype=np.int64)
        prior = np.zeros(0, np.int64) if setup.feature_prior is None else setup.feature_prior.ids
        self.features = np.union1d(truth.feature_ids, prior).astype(np.int64)  # truth's and the prior's

    def fail(self, where: _Where, message: str) -> InvalidInputError:
        return InvalidInputError(f"{where.file if self.files else where.attribute}: {message}")

    def run(self) -> None:
        self.scalars()
        self.times()
        self.ids()
        rows = self.gather_rows()
        self.kinds(rows)
        self.row_ids(rows)
        self.priors()
        self.truth_shapes()

    def priors(self) -> None:
        setup, truth = self.recording.setup, self.recording.truth
        missing = np.setdiff1d(setup.vehicle_prior.ids, truth.vehicle_ids)
        if missing.size:
            raise self.fail(_VEHICLE_PRIOR, f"ids {missing.tolist()} match no vehicle of the truth "
                                            f"(vehicles: {_ids(truth.vehicle_ids)})")
        if setup.feature_prior is not None and truth.feature_ids.size:
            missing = np.setdiff1d(setup.feature_prior.ids, truth.feature_ids)
            if missing.size:
                raise self.fail(_FEATURE_PRIOR, f"ids {missing.tolist()} match no feature of the "
                                                f"truth (features: {_ids(truth.feature_ids)})")

    def truth_shapes(self) -> None:
        setup, truth = self.recording.setup, self.recording.truth
        if truth.vehicle_states.shape[2] != setup.vehicle_layout.dim:
            raise self.fail(_VEHICLE_STATES, f"{truth.vehicle_states.shape[2]} state components, "
                                             f"setup.vehicle_layout.dim is {setup.vehicle_layout.dim}")
        if (setup.feature_layout is not None and truth.feature_ids.size
                and truth.feature_states.shape[2] != setup.feature_layout.dim):
            raise self.fail(_FEATURE_STATES, f"{truth.feature_states.shape[2]} state components, "
                                             f"setup.feature_layout.dim is {setup.feature_layout.dim}")
        n_poses, n_infra = truth.sensor_poses.shape[0], len(setup.infrastructure_ids)
        if n_poses != n_infra:
            raise self.fail(_POSES, f"{n_poses} sensor poses for the {n_infra} infrastructure ids "
                                    f"{list(setup.infrastructure_ids)}: each needs one pose")

    def scalars(self) -> None:
        setup = self.recording.setup
        dt = setup.dt
        if isinstance(dt, bool) or not isinstance(dt, (int, float, np.integer, np.floating)):
            raise self.fail(_DT, f"must be a number of seconds, got {dt!r}")
        n = setup.n_steps
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
            raise self.fail(_N_STEPS, f"must be an integer, got {n!r}")
        n_frames = len(self.recording.frames)
        if n != n_frames:
            raise self.fail(_N_STEPS, f"is {n} but the recording has {n_frames} frames")

    def times(self) -> None:
        t = np.array([frame.t for frame in self.recording.frames])
        if t.size < 2:
            return
        dt = float(self.recording.setup.dt)
        step = np.diff(t)
        bad = ~(np.abs(step - dt) <= DT_RTOL * dt)
        if bad.any():
            k = int(np.flatnonzero(bad)[0]) + 1
            how = ("do not increase" if step[k - 1] <= 0
                   else f"are {float(step[k - 1])!r} s apart, setup.dt is {dt!r}")
            raise self.fail(_TIME, f"times of steps {k - 1} and {k} ({float(t[k - 1])!r}, "
                                   f"{float(t[k])!r}) {how}")

    def ids(self) -> None:
        truth = self.recording.truth
        infrastructure = self.infrastructure
        values, counts = np.unique(infrastructure, return_counts=True)
        if (counts > 1).any():
            raise self.fail(_INFRASTRUCTURE, f"id {int(values[counts > 1][0])} appears twice")
        for a_name, a, b_name, b in (("vehicle", truth.vehicle_ids, "feature", self.features),
                                     ("vehicle", truth.vehicle_ids, "infrastructure", infrastructure),
                                     ("feature", self.features, "infrastructure", infrastructure)):
            both = np.intersect1d(a, b)
            if both.size:
                where = _INFRASTRUCTURE if b_name == "infrastructure" else _FEATURE_PRIOR
                raise self.fail(where, f"ids {both.tolist()} are both {a_name} and {b_name} ids")

    def gather_rows(self) -> dict[str, np.ndarray]:
        """Every measurement row of the recording, flat: step, batch, sensor, subject, origin."""
        frames, origin = self.recording.frames, self.recording.truth.origin
        kinds: list[str] = []
        batch_step: list[int] = []
        dims: list[int] = []
        counts: list[int] = []
        sensor, subject, source = [], [], []
        for frame in frames:
            for kind, batch in frame.batches.items():
                kinds.append(kind)
                batch_step.append(frame.k)
                dims.append(batch.dim)
                counts.append(len(batch))
                sensor.append(batch.sensor)
                subject.append(batch.subject)
                source.append(origin[frame.k][kind])
        counts_a = np.array(counts, dtype=np.int64)

        def flat(parts: list[IntArray]) -> IntArray:
            return np.concatenate(parts) if parts else np.zeros(0, np.int64)

        batch = np.repeat(np.arange(counts_a.size), counts_a)
        return {"kind": np.array(kinds, dtype=object), "batch_step": np.array(batch_step, np.int64),
                "dim": np.array(dims, np.int64), "batch": batch,
                "step": np.array(batch_step, np.int64)[batch] if batch.size else batch,
                "sensor": flat(sensor), "subject": flat(subject), "origin": flat(source)}

    def kinds(self, rows: dict[str, np.ndarray]) -> None:
        sensors = self.recording.setup.sensors
        kinds, steps, dims = rows["kind"], rows["batch_step"], rows["dim"]
        for kind in dict.fromkeys(kinds.tolist()):
            mine = kinds == kind
            if kind not in sensors:
                k = int(steps[mine][0])
                raise self.fail(_KIND, f"step {k} has a batch of kind {kind!r}, which setup.sensors "
                                       f"does not declare (declared: {sorted(sensors)})")
            want = getattr(sensors[kind], "dim", None)
            if want is None:  # a model without a fixed dimension: one dz for the whole run
                want = int(dims[mine][0])
            wrong = mine & (dims != want)
            if wrong.any():
                b = int(np.flatnonzero(wrong)[0])
                raise self.fail(_DIM, f"step {int(steps[b])}, kind {kind!r} has dz = {int(dims[b])}, "
                                      f"its sensor model ({sensors[kind].name}) measures dz = {want}")

    def row_ids(self, rows: dict[str, np.ndarray]) -> None:
        recording = self.recording
        truth, setup = recording.truth, recording.setup
        step = rows["step"]
        if step.size == 0:
            return
        # a row's sensor and subject must be among the frame's vehicles (what estimators
        # see), its origin present in the truth: in_frame / vehicle_present [step, column]
        frames = recording.frames
        in_frame = np.zeros(truth.vehicle_present.shape, dtype=bool)
        in_frame[np.repeat(np.arange(len(frames)), [f.vehicles.size for f in frames]),
                 lookup_ids(truth.vehicle_ids, np.concatenate([f.vehicles for f in frames]))[0]] = True
        col, known = lookup_ids(truth.vehicle_ids, np.concatenate(
            [rows["sensor"], rows["subject"], rows["origin"]]))
        col = col.reshape(3, -1)
        known = known.reshape(3, -1)
        steps = np.broadcast_to(step, col.shape)
        present = np.zeros_like(known)
        for j, table in enumerate((in_frame, in_frame, truth.vehicle_present)):
            present[j, known[j]] = table[steps[j, known[j]], col[j, known[j]]]
        infrastructure = np.isin(rows["sensor"], self.infrastructure)
        features = self.features
        if truth.feature_ids.size == 0 and setup.feature_layout is not None:
            # feature truth not recorded: any id that is not a vehicle or sensor is a feature
            not_feature = np.isin(rows["subject"], self.infrastructure)
            subject_feature = ~known[1] & ~not_feature
            origin_feature = ~known[2] & ~np.isin(rows["origin"], self.infrastructure)
        else:
            subject_feature = np.isin(rows["subject"], features)
            origin_feature = np.isin(rows["origin"], features)
        checks = (
            (_SENSOR, rows["sensor"], (rows["sensor"] == -1) | present[0] | infrastructure,
             "a vehicle of the frame at that step, an infrastructure sensor or -1"),
            (_SUBJECT, rows["subject"], (rows["subject"] == -1) | present[1] | subject_feature,
             "a vehicle of the frame at that step, a feature or -1"),
            (_ORIGIN, rows["origin"], (rows["origin"] == -1) | present[2] | origin_feature,
             "a vehicle present at that step, a feature or -1 (clutter)"),
        )
        for j, (where, ids, ok, must) in enumerate(checks):
            if not ok.all():
                i = int(np.flatnonzero(~ok)[0])
                b = int(rows["batch"][i])
                row = i - int(np.flatnonzero(rows["batch"] == b)[0])
                what = ("is a vehicle absent at that step" if known[j, i]
                        else "is no entity of the recording")
                raise self.fail(where, f"step {int(step[i])}, kind {rows['kind'][b]!r}, row {row}: "
                                       f"id {int(ids[i])} {what}; it must be {must}")


def _ids(ids: IntArray) -> str:
    shown = ids[:10].tolist()
    return str(shown) if ids.size <= 10 else f"{shown[:-1]} … ({ids.size} ids)"


def validate_recording(recording: Recording, *, files: bool = False) -> Recording:
    """Raise `InvalidInputError` unless `recording` means what it says (rules: module docstring).

    Parameters
    ----------
    recording : the recording to check (its containers have already checked structure).
    files : name the field as the file and column of `cooploc.io`'s layout (what
        `load_recording` does) instead of as the attribute of the `Recording`.

    Returns the recording unchanged, so that ``validate_recording(Recording(...))`` reads.
    """
    if not isinstance(recording, Recording):
        raise InvalidInputError(f"validate_recording needs a Recording, got {type(recording).__name__}")
    _Checker(recording, files).run()
    return recording
