"""Where the city-mode `rsu-bp` loses against `oracle-kf`: truth-informed pieces, one at a time.

    python benchmarks/rsu_bp_city_oracles.py                       # sumo-grid-tlr, every variant
    python benchmarks/rsu_bp_city_oracles.py --preset sumo-braunschweig-tlr --duration 60 \\
        --variants base,known-association --out b.json

A diagnosis, not an estimator: it reads the truth to replace one piece of `rsu-bp`'s
unknown-feature model (`rsu_bp.tracking`) at a time, so that the accuracy each piece
costs shows in the vehicle RMSE:

- ``base``: `rsu-bp` as registered.
- ``exact-map``: before every step, the potential features are the true features present
  (covariance 10⁻⁶ I, existence 0.999); association, births and vehicles as usual.
- ``known-association``: a row is gated only with the track that the first row of its
  true feature started, and it starts a track only if its feature has none yet.
- ``exact-map+known-association``: both (no births).
  The exact-map variants run with ``feature_messages="fixes"`` whatever ``--param`` says:
  the true map replaces the learned one before every step, so how the map is learned
  does not enter (with ``--param feature_messages=tracks`` the others learn it from the
  vehicles' track messages, `rsu_bp.map_messages`).
- ``+matched-motion`` after any of these: the estimator's vehicle motion model is the
  one SUMO steps by (x_{k+1} = x_k + dt v_{k+1}, v_{k+1} = v_k + w,
  `EulerVelocity`) instead of the scenario's constant velocity; also for
  ``gnss-kf`` and ``oracle-kf``.

For each: vehicle RMSE and mean position NEES over all steps, the ESS of the vehicles'
importance weights (N_p = 600), and the features' RMSE and NEES against the nearest
true feature present, with the share of reported features that duplicate another's.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import environment, recording, write_json

from cooploc.estimators import make_estimator
from cooploc.estimators.rsu_bp import RsuBPParams, tracking
from cooploc.metrics import VEHICLE, evaluate
from cooploc.motion import ConstantVelocity
from cooploc.types import Recording

VARIANTS = ("gnss-kf", "oracle-kf", "base", "exact-map", "known-association", "exact-map+known-association")


@dataclasses.dataclass(frozen=True)
class EulerVelocity(ConstantVelocity):
    """v_{k+1} = v_k + w, w ~ N(0, q dt I); x_{k+1} = x_k + dt v_{k+1}: SUMO's Euler step.

    Q = q dt [[dt² I, dt I], [dt I, I]] with the transition of `ConstantVelocity`.
    """

    def noise_covariance(self, dt: float, mean: Any = None) -> np.ndarray:
        q, eye = self.noise_density, np.eye(2)
        return np.block([[q * dt**3 * eye, q * dt**2 * eye], [q * dt**2 * eye, q * dt * eye]])


class _Truthful:
    """Patches of `tracking.FeatureTracker` that read the truth of the current step."""

    def __init__(self, rec: Recording, exact_map: bool, known: bool) -> None:
        self.rec, self.exact_map, self.known = rec, exact_map, known
        self.k = 0
        self.track_of: dict[int, int] = {}     # true feature id -> the track its rows go to
        self.row_origin = np.zeros(0, np.int64)
        names = ("predict", "update", "_gate", "_births")
        self.saved = {n: getattr(tracking.FeatureTracker, n) for n in names}

    def install(self) -> None:
        T, me, saved = tracking.FeatureTracker, self, self.saved

        def predict(tracker: Any, steps: int | None) -> None:
            saved["predict"](tracker, steps)
            if me.exact_map:
                truth, k = me.rec.truth, me.k
                present = truth.feature_present[k]
                f = tracker.features
                f.ids = truth.feature_ids[present].astype(np.int64)
                f.mean = truth.feature_states[k][present].copy()
                tiny = 1e-6 * np.eye(tracker.df)
                f.cov = np.broadcast_to(tiny, (f.ids.size, *tiny.shape)).copy()
                f.existence = np.full(f.ids.size, 0.999)
                tracker.sent = {}
                if me.known:
                    me.track_of = {int(i): int(i) for i in f.ids}

        def update(tracker: Any, vehicle_ids: Any, v_mean: Any, v_cov: Any, v2f: Any, gnss: Any) -> Any:
            frame_rows = me.rec.frames[me.k].batches["v2f"]
            origin = np.asarray(me.rec.truth.origin[me.k]["v2f"])
            # the rows handed over are a subset of the frame's, in order: match by value
            where = {tuple(z): i for i, z in enumerate(map(tuple, frame_rows.z))}
            me.row_origin = origin[[where[tuple(z)] for z in map(tuple, v2f.z)]]
            out = saved["update"](tracker, vehicle_ids, v_mean, v_cov, v2f, gnss)
            for o, t in zip(me.row_origin.tolist(), out[1].tolist(), strict=True):
                if o >= 0 and t >= 0 and o not in me.track_of:
                    me.track_of[o] = t
            return out

        def gate(tracker: Any, v2f: Any, s_row: Any, c_mean: Any, c_cov: Any) -> Any:
            f = tracker.features
            column = {int(i): j for j, i in enumerate(f.ids)}
            k = np.array([column.get(me.track_of.get(int(o), -1), -1) for o in me.row_origin], dtype=np.int64)
            r = np.flatnonzero(k >= 0)
            k = k[r]
            Hf = tracker.Hf
            resid = v2f.z[r] - (f.mean[k] @ Hf.T - c_mean[s_row[r]])
            S = v2f.cov[r] + Hf @ f.cov[k] @ Hf.T + c_cov[s_row[r]]
            d2 = np.einsum("pi,pi->p", resid, np.linalg.solve(S, resid[..., None])[..., 0])
            log_beta = -0.5 * (resid.shape[1] * np.log(2 * np.pi) + np.linalg.slogdet(S)[1] + d2)
            return r, k, log_beta

        def births(tracker: Any, v2f: Any, s_row: Any, vehicle_ids: Any, belief: Any, r_new: Any,
                   track: Any, gnss: Any, **kwargs: Any) -> int:
            if me.exact_map:
                return 0
            new = np.array([o >= 0 and o not in me.track_of for o in me.row_origin.tolist()], dtype=bool)
            r_new = np.where(new, np.maximum(r_new, 0.9), 0.0)
            return saved["_births"](tracker, v2f, s_row, vehicle_ids, belief, r_new, track, gnss, **kwargs)

        T.predict = predict
        if self.known:
            T.update, T._gate, T._births = update, gate, births

    def remove(self) -> None:
        for name, fn in self.saved.items():
            setattr(tracking.FeatureTracker, name, fn)


def _feature_scores(rec: Recording, estimates: list) -> tuple[float, float, float]:
    """RMSE and mean NEES of the reported features against the nearest true feature present,
    and the share of reported features that are a second track of a true feature (one that
    is already the nearest of another reported feature)."""
    err2, nees, extra, shown = [], [], 0, 0
    for k, est in enumerate(estimates):
        f = est.features
        present = rec.truth.feature_present[k]
        if f is None or not len(f) or not present.any():
            continue
        true = rec.truth.feature_states[k][present][:, :2]
        d = np.linalg.norm(f.mean[:, None, :2] - true[None], axis=2)
        nearest = d.argmin(axis=1)
        extra += nearest.size - np.unique(nearest).size
        shown += nearest.size
        e = true[nearest] - f.mean[:, :2]
        err2.append((e**2).sum(axis=1))
        nees.append(np.einsum("fi,fi->f", e, np.linalg.solve(f.cov[:, :2, :2], e[..., None])[..., 0]))
    if not err2:
        return float("nan"), float("nan"), float("nan")
    return (float(np.sqrt(np.concatenate(err2).mean())), float(np.concatenate(nees).mean()),
            extra / shown)


def run_variant(rec: Recording, variant: str, seed: int, overrides: dict[str, Any] | None = None
                ) -> dict[str, Any]:
    matched_motion = variant.endswith("+matched-motion")
    name = variant.removesuffix("+matched-motion")
    setup = rec.setup
    if matched_motion:
        setup = dataclasses.replace(setup, vehicle_motion=EulerVelocity(setup.vehicle_motion.noise_density))
    patch = None
    if name in ("gnss-kf", "oracle-kf"):
        est = make_estimator(name, setup, None, np.random.default_rng(seed), rec.truth)
    else:
        patch = _Truthful(rec, exact_map="exact-map" in name, known="known-association" in name)
        patch.install()
        params = RsuBPParams(n_particles=600).with_overrides(overrides or {})
        if "exact-map" in name:
            # the true map replaces the learned one before every step: how it is learned
            # does not matter, and only the fixes' bookkeeping is reset with it
            params = params.with_overrides({"feature_messages": "fixes"})
        est = make_estimator("rsu-bp", setup, params, np.random.default_rng(seed))
    try:
        estimates, ess, seconds = [], [], 0.0
        for k, frame in enumerate(rec.frames):
            if patch is not None:
                patch.k = k
            start = time.perf_counter()
            out = est.step(frame)
            seconds += time.perf_counter() - start
            estimates.append(out)
            if len(out.info.get("vehicle_ess", ())):
                ess.append(out.info["vehicle_ess"])
    finally:
        if patch is not None:
            patch.remove()
    table = evaluate(rec, estimates)
    v = table.kind == VEHICLE
    result = {"vehicle_rmse": float(np.sqrt(np.mean(table.err_pos[v] ** 2))),
              "vehicle_nees_mean": float(np.nanmean(table.nees[v])),
              "vehicle_nees_median": float(np.nanmedian(table.nees[v])),
              "steps_per_second": len(rec.frames) / seconds}
    if name not in ("gnss-kf", "oracle-kf"):
        ess_all = np.concatenate(ess) if ess else np.zeros(1)
        result.update(ess_min=float(ess_all.min()), ess_p5=float(np.percentile(ess_all, 5)),
                      ess_median=float(np.median(ess_all)))
    if name != "gnss-kf":
        (result["feature_rmse_nearest"], result["feature_nees_mean"],
         result["duplicate_share"]) = _feature_scores(rec, estimates)
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="sumo-grid-tlr")
    parser.add_argument("--duration", type=float, default=None, help="s of traffic (default: the preset's)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help="comma-separated; append +matched-motion to any")
    parser.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                        help="an rsu-bp parameter for every variant (repeatable)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    results: dict[str, Any] = {"environment": environment(), "preset": args.preset, "seed": args.seed,
                               "duration": args.duration, "params": args.param, "variants": {}}
    overrides = dict(item.split("=", 1) for item in args.param)
    rec = recording(args.preset, args.seed, {"duration": args.duration} if args.duration else None)
    print(f"{args.preset}: {len(rec.frames)} steps, {rec.truth.vehicle_ids.size} vehicles, "
          f"{rec.truth.feature_ids.size} features")
    for variant in args.variants.split(","):
        r = run_variant(rec, variant, args.seed, overrides)
        results["variants"][variant] = r
        print(f"{variant:45s} " + "  ".join(f"{k} {v:.3g}" for k, v in r.items()), flush=True)
    if args.out is not None:
        write_json(results, args.out)


if __name__ == "__main__":
    main()
