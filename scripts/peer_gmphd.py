"""A peer for the co-channel count (issue 54): Stone Soup's GM-PHD filter with a bearing measurement model on the
same readings as scripts/co_channel.py, the count and each transmitter's accuracy in one table beside ours.

    python scripts/peer_gmphd.py [--runs 20] [--jobs 2] [--cells "two 50/50,two 80/20,one"]

Stone Soup 1.9's GM-PHD (PHDUpdater over ExtendedKalmanUpdater, GaussianMixtureHypothesiser over a Mahalanobis
DistanceHypothesiser, GaussianMixtureReducer), set up as a static-emitter, bearing-only problem: the state is a
place (random walk 1e-6 m^2/s, survival 1), each reading one scan with one detection, `Cartesian2DToBearing` at
the antenna's true place with the reading's true noise (the peer is told what ours is not). Static emitters need
no birth over time: the prior intensity is a grid of Gaussian components over the drive's radio reach (ours,
global_search.radio_reach), their weights summing to `--expected` (1.5) targets; the detection probability of a
transmitter is taken as one over the true count (its air-time share, which the peer is also told) and the clutter
as the readings' true wild share, uniform in bearing. The count is the sum of the weights at the end, rounded (the
standard GM-PHD estimate); the places are that many heaviest components after merging, each scored like ours
(matched to a truth, its error against the CRLB of the readings that truth sent, inside its 95 % ellipse).
Ours: the same run as scripts/co_channel.py (the default configuration, receiver not told).
"""
from __future__ import annotations

import argparse
import itertools
import math
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import co_channel  # noqa: E402

from aoa_localizer.engine.crlb import crlb_rmse, inside_ellipse  # noqa: E402
from aoa_localizer.engine.geodesy import azimuth_to_enu  # noqa: E402
from aoa_localizer.engine.inference.global_search import radio_reach  # noqa: E402
from aoa_localizer.simulation.scenarios import simulate  # noqa: E402

try:
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.gaussianmixture import GaussianMixtureHypothesiser
    from stonesoup.measures import Mahalanobis
    from stonesoup.mixturereducer.gaussianmixture import GaussianMixtureReducer
    from stonesoup.models.measurement.nonlinear import Cartesian2DToBearing
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, RandomWalk
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import TaggedWeightedGaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater
    from stonesoup.updater.pointprocess import PHDUpdater
except ImportError:  # the `bench` extra is not installed
    PHDUpdater = None

T0 = datetime(2026, 1, 1)
GRID = 12  # prior components per side
GATE = 25.0  # squared Mahalanobis distance beyond which a component is not updated by a reading


def gm_phd(data, expected: float) -> tuple[float, list[tuple[np.ndarray, np.ndarray]], float]:
    """(expected count, the places of the rounded count: mean and covariance, seconds) of one run."""
    north = data.frame.north_angle(*data.frame.to_geodetic(data.sensor_enu[:, 0], data.sensor_enu[:, 1])[:2])
    theta = azimuth_to_enu(data.bearings[:, 1], north)
    east, north_c, scale = radio_reach(data.sensor_enu)
    step = 2.0 * scale / GRID
    axis = np.linspace(-scale + step / 2, scale - step / 2, GRID)
    transition = CombinedLinearGaussianTransitionModel([RandomWalk(1e-6), RandomWalk(1e-6)])
    predictor = ExtendedKalmanPredictor(transition)
    updater = ExtendedKalmanUpdater(measurement_model=None)
    truths = len(data.transmitters_enu) if data.transmitters_enu is not None else 1
    phd = PHDUpdater(updater, clutter_spatial_density=max(float(data.wild.mean()), 1e-3) / (2 * math.pi),
                     prob_detection=0.95 / truths, prob_survival=1.0)
    hypothesiser = GaussianMixtureHypothesiser(DistanceHypothesiser(predictor, updater, Mahalanobis(), GATE),
                                               order_by_detection=True)
    reducer = GaussianMixtureReducer(prune_threshold=1e-15, merge_threshold=4.0, max_number_components=300)
    components = [TaggedWeightedGaussianState(np.array([[east + x], [north_c + y]]), np.eye(2) * step**2,
                                              weight=expected / GRID**2, tag=f"prior {i}", timestamp=T0)
                  for i, (x, y) in enumerate(itertools.product(axis, axis))]
    started = time.perf_counter()
    for stamp, th, place, sigma in zip(data.bearings[:, 0], theta, data.sensor_enu, data.sigma, strict=True):
        when = T0 + timedelta(seconds=float(stamp))
        model = Cartesian2DToBearing(ndim_state=2, mapping=(0, 1), noise_covar=np.array([[sigma**2]]),
                                     translation_offset=np.array([[place[0]], [place[1]]]))
        detection = Detection(np.array([[th]]), timestamp=when, measurement_model=model)
        hypotheses = hypothesiser.hypothesise(components, {detection}, when)
        components = list(reducer.reduce(list(phd.update(hypotheses))))
    seconds = time.perf_counter() - started
    total = float(sum(c.weight for c in components))
    heaviest = sorted(components, key=lambda c: -c.weight)[: max(round(total), 0)]
    return total, [(np.asarray(c.mean, float).ravel(), np.asarray(c.covar, float)) for c in heaviest], seconds


def one_run(name: str, run: int, expected: float) -> dict:
    sc = co_channel.placed(co_channel.cells()[name], run)
    data = simulate(sc, run)
    total, places, seconds = gm_phd(data, expected)
    truths = data.transmitters_enu if data.transmitters_enu is not None else data.emitter_enu[None, :]
    out: dict = {"expected": total, "count": len(places), "seconds": seconds, "transmitters": []}
    if len(places) == len(truths):
        order = min(itertools.permutations(range(len(truths))),
                    key=lambda p: sum(np.hypot(*(places[i][0] - truths[j])) for i, j in enumerate(p)))
        for i, j in enumerate(order):
            mine = ((data.source == j) if data.source is not None else np.ones(len(data.wild), bool)) & ~data.wild
            err = places[i][0] - truths[j]
            out["transmitters"].append({"error": float(np.hypot(*err)),
                                        "crlb": crlb_rmse(truths[j], data.sensor_enu[mine], data.sigma[mine]),
                                        "inside": bool(inside_ellipse(err, places[i][1]))})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cells", default="two 50/50,two 80/20,one,wild 20 %,reflector 20 %")
    ap.add_argument("--expected", type=float, default=1.5, help="the prior's expected number of transmitters")
    args = ap.parse_args()
    if PHDUpdater is None:
        print("peer_gmphd: Stone Soup is not installed (pip install '.[bench]')", file=sys.stderr)
        return 2
    names = args.cells.split(",")
    print("| cell | filter | count right | count (runs) | error / CRLB (RMS, each transmitter) | inside 95 % | "
          "s per run |")
    print("|---|---|---|---|---|---|---|")
    with ProcessPoolExecutor(args.jobs) as pool:
        for name in names:
            sc = co_channel.cells()[name]
            truth = len(sc.co_shares) if sc.co_shares and sc.bursts_s is not None else 1
            for label, runner, extra in (("GM-PHD (Stone Soup)", one_run, [args.expected] * args.runs),
                                         ("ours", co_channel.one_run, None)):
                started = time.perf_counter()
                res = list(pool.map(runner, [name] * args.runs, range(args.runs), *([extra] if extra else [])))
                per_run = (time.perf_counter() - started) * args.jobs / args.runs
                counts = [r["count"] for r in res]
                tally = ", ".join(f"{c}: {counts.count(c)}" for c in sorted(set(counts)))
                scored = [t for r in res for t in r.get("transmitters", [])]
                ratio = (math.sqrt(statistics.mean(t["error"] ** 2 for t in scored))
                         / math.sqrt(statistics.mean(t["crlb"] ** 2 for t in scored))) if scored else float("nan")
                inside = f"{sum(t['inside'] for t in scored)}/{len(scored)}" if scored else "-"
                print(f"| {name} | {label} | {counts.count(truth)}/{len(res)} | {tally} | {ratio:.2f} | {inside} | "
                      f"{per_run:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
