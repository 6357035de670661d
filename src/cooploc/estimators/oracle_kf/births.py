"""Where a feature's belief starts in `oracle-kf` (both forms): its prior, or its first fix.

A feature listed in `Setup.feature_prior` starts from that prior predicted from step 0
to the step it is first seen (what keeping it in the state unseen would give). Any
other starts broad around its first fix, f ≈ x̂_s + z, from the predicted mean of the
vehicle s whose row saw it first.
"""

from __future__ import annotations

import numpy as np

from cooploc.estimators.base import default_birth_cov, predict_steps
from cooploc.gaussian import Gaussians
from cooploc.types import FloatArray, Frame, IntArray, Setup

__all__ = ["feature_births"]


def feature_births(setup: Setup, frame: Frame, ids: IntArray, first_rows: IntArray,
                   sensor_means: FloatArray) -> Gaussians:
    """Initial beliefs of features `ids` (n,) first seen in `frame`.

    `first_rows` (n,) are the V2F rows that saw each first, `sensor_means` (n, dx) the
    predicted means of the vehicles that made those rows.
    """
    dx = setup.vehicle_layout.dim
    df = setup.feature_layout.dim
    mean = np.zeros((ids.size, df))
    birth = default_birth_cov(setup)[:df, :df] if df == dx else 1e4 * np.eye(df)
    cov = np.repeat(birth[None], ids.size, axis=0)
    prior = setup.feature_prior
    known = np.isin(ids, prior.ids) if prior is not None else np.zeros(ids.size, bool)
    if known.any():
        p = prior.take(ids[known])
        predicted = predict_steps(Gaussians(p.mean, p.cov), setup.feature_motion, setup.dt, frame.k)
        mean[known], cov[known] = predicted.mean, predicted.cov
    pos_f = list(setup.sensors["v2f"].state_indices)
    unknown = ~known
    z = frame.batches["v2f"].z[first_rows[unknown]]
    mean[np.ix_(unknown, pos_f)] = sensor_means[unknown][:, pos_f] + z   # f ≈ x̂_s + z
    return Gaussians(mean, cov)
