"""Save and load a `Recording` as a folder of Parquet tables and one JSON file.

Modules: `layout` (file names, format version), `save` (`save_recording`), `load`
(`load_recording`, with the checks that name the file and field of bad input),
`validate` (`validate_recording`: does a well-formed recording mean what it says — ids
of entities that exist, declared kinds, times ``dt`` apart, …; run by `load_recording`,
and callable on a `Recording` built in Python; rules in `cooploc.io.validate` and
``docs/recordings.md``).

This is also the format in which users bring their own data: write the six files
below (with pyarrow, pandas, polars, …) and `load_recording(folder)` gives a
`Recording` that every estimator and metric accepts. `save_recording` writes exactly
this layout, and a saved recording loads back bit for bit (float64 throughout, same
ids, same row order in every batch, same batch kinds — empty batches included).

Folder layout (format version 1)
--------------------------------
``setup.json`` — the static `Setup`, one JSON object:

- ``format_version``: 1.
- ``dt`` (s), ``n_steps``, ``description``, ``detection_probability``,
  ``clutter_rate``, ``infrastructure_ids`` (list of ints).
- ``vehicle_layout`` / ``feature_layout``: ``{"dim", "position", "velocity",
  "heading"}`` (`StateLayout.to_dict`), or null for features.
- ``vehicle_motion`` / ``feature_motion``: ``{"model": "constant-velocity", …}``
  (`MotionModel.to_dict`, read by `cooploc.motion.motion_from_dict`), or null.
- ``sensors``: ``{kind: {"model": "gnss-position", …}}`` (`SensorModel.to_dict`,
  read by `cooploc.sensors.sensor_from_dict`).
- ``vehicle_prior`` / ``feature_prior``: ``{"ids", "mean", "cov", "dim"}``
  (`StateSet.to_dict` plus the state dimension, which an empty set cannot show), or
  null for features.
- ``birth_cov`` ((dx, dx) nested list or null), ``clutter_region`` ((d, 2) or null).

Required: ``format_version``, ``dt``, ``n_steps``, ``vehicle_layout``,
``vehicle_motion``, ``vehicle_prior``; the others default to the `Setup` defaults
(no sensors, no features, P_D = 1, no clutter, no infrastructure). Floats are written
with Python's shortest round-trip repr, so they load back bit for bit; an infinite float
inside ``sensors`` (a radar's unlimited ``max_range``) is the string ``"inf"``, so the
file stays strict JSON.

``frames.parquet`` — one row per step (in any order):

===========  ===============================  ========================================
column       type                             meaning
===========  ===============================  ========================================
step         int64                            k = 0 … T−1, each exactly once
t            float64                          time in s
vehicles     list<int64>                      ids of the vehicles present, in order
links        list<fixed_size_list<int64, 2>>  V2V edges; list<list<int64>> of [a, b]
                                              pairs is accepted too
batch_kinds  list<string>                     the measurement kinds of this step
batch_dims   list<int64>                      dz of each kind, aligned with batch_kinds
===========  ===============================  ========================================

A kind listed in ``batch_kinds`` with no rows in ``measurements.parquet`` is an empty
batch (e.g. a V2F sensor that saw nothing); a kind not listed is absent at that step.

``measurements.parquet`` — one row per measurement row of every batch:

=========  ============  ==============================================================
column     type          meaning
=========  ============  ==============================================================
step       int64         the step of the batch
t          float64       time of the step (optional when reading; must match frames)
kind       string        the batch kind (must be listed for that step in frames)
row        int64         position of the row inside its batch: 0 … M−1, each once
sensor     int64         id of the measuring entity, −1 if unknown
subject    int64         id of the measured entity, −1 if the association is unknown
origin     int64         truth: id of the entity the row came from, −1 for clutter
z          list<double>  the dz measured values
cov        list<double>  the dz × dz noise covariance, flattened row-major (dz² values)
=========  ============  ==============================================================

Rows may come in any order; they are sorted by (step, kind order of the frame, row).
Different kinds (and steps) may have different dz, hence the list columns.

``truth_vehicles.parquet`` and ``truth_features.parquet`` — true states:
columns ``step`` (int64), ``id`` (int64), ``present`` (bool) and ``x_0 … x_{d−1}``
(float64, the state components; the columns fix d even when the table is empty), and
in ``truth_vehicles.parquet`` an optional ``heading`` (float64, rad: `Truth.vehicle_heading`,
the true heading of a scenario whose state layout has none; absent: None).
`save_recording` writes every (step, id) pair, absent ones included; when reading, a
missing pair is an absent entity with a zero state. Ids are ordered by first
appearance.

``sensor_poses.parquet`` — one row per infrastructure sensor, in
``infrastructure_ids`` order: ``sensor`` (int64 id, or −1 if unknown), ``x``, ``y``
(m), ``yaw`` (rad).

Writing one by hand, e.g. the measurements of one GNSS fix::

    pq.write_table(pa.table({
        "step": [0], "kind": ["gnss"], "row": [0], "sensor": [7], "subject": [7],
        "origin": [7], "z": [[12.5, -3.0]], "cov": [[4.0, 0.0, 0.0, 4.0]],
    }), folder / "measurements.parquet")

Truth origins are stored per measurement row, so an origin entry for a kind that has
no batch at that step is not kept. Extra columns are ignored when reading. A missing
file, malformed content, or content that cannot mean what it says (`validate`) raises
`InvalidInputError` naming the file and the field (and the step and value).
"""

from __future__ import annotations

from cooploc.io.layout import FORMAT_VERSION
from cooploc.io.load import load_recording
from cooploc.io.save import save_recording
from cooploc.io.validate import validate_recording

__all__ = ["FORMAT_VERSION", "load_recording", "save_recording", "validate_recording"]
