"""Stone Soup's GM-PHD run with the models of `gm-phd`: the reference it is checked and timed against.

Stone Soup (dstl) is a test-only dependency (the `dev` extra), so this lives with the
tests, not in the package. Used by tests/test_gm_phd.py (the cross-check) and by
benchmarks/zhang2016.py (the timing), which puts this folder on its path.
"""

from __future__ import annotations

import datetime
import time

import numpy as np

from cooploc.estimators.gm_phd import GMPHD, GMPHDParams
from cooploc.types import FloatArray, Recording

__all__ = ["stonesoup_reference"]


def stonesoup_reference(recording: Recording, params: GMPHDParams | None = None
                        ) -> tuple[list[tuple[FloatArray, FloatArray]], float]:
    """Stone Soup's GM-PHD on the GPS rows of `recording` with the models of `GMPHD`.

    Returns per step (weights (J,), means (J, dx) in cooploc's layout) after reduction,
    and the seconds spent in Stone Soup. Needs the test-only dependency ``stonesoup``.
    No births (`birth_weight` must be 0): Stone Soup drops the missed-detection term of
    birth components, which Vo & Ma keep. Stone Soup applies p_S inside its update, also
    at step 0 where we do not predict: compare with `survival_probability` = 1. Stone Soup
    caps a merged weight at 1, so compare where no two targets merge.
    """
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
    from stonesoup.measures import Mahalanobis
    from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (
        CombinedLinearGaussianTransitionModel,
        ConstantVelocity,
    )
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import TaggedWeightedGaussianState
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.pointprocess import PHDUpdater

    params = params or GMPHDParams()
    setup = recording.setup
    ours = GMPHD(setup, params, np.random.default_rng(0))
    order = [0, 2, 1, 3]   # cooploc [p_x, p_y, v_x, v_y] → Stone Soup [x, ẋ, y, ẏ]
    back = np.argsort(order)
    density = float(setup.vehicle_motion.noise_density)  # type: ignore[attr-defined]
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(density)] * 2)
    gnss = recording.frames[0].batches["gnss"]
    measurement = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.array(gnss.cov[0]))
    predictor = KalmanPredictor(transition)
    kalman = KalmanUpdater(measurement)
    updater = PHDUpdater(kalman, clutter_spatial_density=ours.kappa, prob_detection=ours.p_d,
                         prob_survival=params.survival_probability)
    hypothesiser = GaussianMixtureHypothesiser(
        DistanceHypothesiser(predictor, kalman, Mahalanobis(), missed_distance=np.inf),
        order_by_detection=True)
    reducer = GaussianMixtureReducer(prune_threshold=params.prune_threshold, pruning=True,
                                     merge_threshold=params.merge_threshold, merging=True,
                                     max_number_components=params.max_components)
    start_time = datetime.datetime(2016, 1, 1)
    first = ours._initial(recording.frames[0])
    components = [
        TaggedWeightedGaussianState(state_vector=mean[order][:, None], covar=cov[np.ix_(order, order)],
                                    weight=1.0, tag=str(i), timestamp=start_time)
        for i, (mean, cov) in enumerate(zip(first.mean, first.cov, strict=True))
    ]
    out, spent = [], 0.0
    for frame in recording.frames:
        timestamp = start_time + datetime.timedelta(seconds=frame.t - recording.frames[0].t)
        rows = frame.batches["gnss"]
        detections = {Detection(z[:, None], timestamp=timestamp, measurement_model=measurement)
                      for z in rows.z}
        begin = time.perf_counter()
        # at step 0 the timestamps agree: Stone Soup predicts over 0 s (identity), as we skip it
        hypotheses = hypothesiser.hypothesise(components, detections, timestamp,
                                              order_by_detection=True)
        components = reducer.reduce(list(updater.update(hypotheses)))
        spent += time.perf_counter() - begin
        weights = np.array([float(c.weight) for c in components])
        means = np.array([np.asarray(c.state_vector, dtype=float)[:, 0][back] for c in components])
        out.append((weights, means.reshape(-1, 4)))
    return out, spent
