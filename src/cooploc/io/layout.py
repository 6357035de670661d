"""The folder layout of a saved recording: file names and format version (see `cooploc.io`)."""

from __future__ import annotations

import re

__all__ = [
    "FORMAT_VERSION",
    "FRAMES_FILE",
    "HEADING_COLUMN",
    "INFINITY",
    "MEASUREMENTS_FILE",
    "SENSOR_POSES_FILE",
    "SETUP_FILE",
    "STATE_COLUMN",
    "TRUTH_FEATURES_FILE",
    "TRUTH_VEHICLES_FILE",
]

FORMAT_VERSION = 1

SETUP_FILE = "setup.json"
FRAMES_FILE = "frames.parquet"
MEASUREMENTS_FILE = "measurements.parquet"
TRUTH_VEHICLES_FILE = "truth_vehicles.parquet"
TRUTH_FEATURES_FILE = "truth_features.parquet"
SENSOR_POSES_FILE = "sensor_poses.parquet"

#: the state columns x_0 … x_{d−1} of the truth tables
STATE_COLUMN = re.compile(r"x_(\d+)")
#: the optional column of truth_vehicles.parquet with `Truth.vehicle_heading`
HEADING_COLUMN = "heading"

#: how setup.json spells infinite floats (strict JSON has no Infinity), e.g. a radar's
#: unlimited ``max_range``; read back inside ``sensors`` only
INFINITY = {"inf": float("inf"), "-inf": float("-inf")}
