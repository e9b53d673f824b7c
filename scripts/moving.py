"""Moving transmitters (issue 68): the Localizer's defaults on transmitters that move, against the posterior
Cramer-Rao bound, beside Stone Soup's bearing-only particle filter; and the static cells, whose transmitter stands.

    python scripts/moving.py [--cells walker car drone stand_walk_stand] [--static seed wild20 ...] [--runs 20]
                             [--jobs 2] [--no-peer]

Moving cells (simulation.scenarios.moving_cells): over the estimates after SETTLE_S, the RMS error against the
transmitter's place at each estimate's stamp over the RMS PCRB there (engine.crlb.pcrb_moving: an OU velocity of
the cell's speed and the watch's correlation time), the share inside the 95 % ellipse, the share published as
`moving` (and the median error over the median PCRB: a static estimate of a mover can be kilometres off), and
the time from the start of motion to the first estimate with motion_probability >= 0.9; Stone Soup's
particle filter (a constant-velocity model of the cell's speed, given the true noise, begun on the first bearing's
line as the watch is) over the same readings, its RMS after SETTLE_S and its cost per reading. Static cells: the
final motion_probability, runs whose final estimate is `static` with p(static) >= 0.95, and estimates not `static`.
"""
from __future__ import annotations

import argparse
import logging
import math
import multiprocessing
import time
from datetime import datetime, timedelta

import numpy as np

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.crlb import ELLIPSE_95, pcrb_moving
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.inference.motion import VELOCITY_TAU_S
from aoa_localizer.simulation.evaluation import scenario_config
from aoa_localizer.simulation.scenarios import SCENARIOS, ScenarioData, moving_cells, robustness_cells, simulate

MOVING = moving_cells()
STATIC = {**SCENARIOS, **robustness_cells()}
SETTLE_S = 200.0  # estimates before this are the start's, not the track's
PEER_PARTICLES = 1000


def moving_run(job: tuple[str, int, bool]) -> dict:
    logging.getLogger("aoa_localizer").setLevel(logging.ERROR)
    name, seed, peer = job
    sc = MOVING[name]
    data = simulate(sc, seed)
    frame = LocalFrame(*sc.datum)
    stamps = data.bearings[:, 0]
    bound = pcrb_moving(data.emitter_at(stamps), data.sensor_enu, data.sigma, stamps, max(sc.emitter_speed, 0.5),
                        VELOCITY_TAU_S)
    rows = []
    t0 = time.perf_counter()
    for est in Localizer(scenario_config(data, LocalizerConfig(seed=1000 + seed))).run(data.inputs()):
        if est is None:
            continue
        east, north = frame.to_enu(est.lat, est.lon)
        d = np.array([east, north]) - data.emitter_at(np.array(est.stamp))
        k = max(0, int(np.searchsorted(stamps, est.stamp, side="right")) - 1)
        rows.append((est.stamp, float(d @ d), float(d @ np.linalg.solve(est.cov, d)) <= ELLIPSE_95,
                     est.motion == "moving", est.motion_probability, bound[k] ** 2))
    cost = time.perf_counter() - t0
    a = np.array(rows, float)
    late = a[:, 0] > SETTLE_S
    sure = a[(a[:, 0] >= sc.emitter_start_s) & (a[:, 4] >= 0.9), 0]
    out = {"name": name, "err2": a[late, 1].mean(), "bound2": a[late, 5].mean(), "in95": a[late, 2].mean(),
           "median": float(np.median(np.sqrt(a[late, 1]))), "bound_median": float(np.median(np.sqrt(a[late, 5]))),
           "moving": a[late, 3].mean(), "to_sure": (sure[0] - sc.emitter_start_s) if sure.size else math.inf,
           "us_per_reading": 1e6 * cost / len(stamps)}
    if peer:
        out.update(stone_soup(data, seed))
    return out


def stone_soup(data: ScenarioData, seed: int) -> dict:
    """Stone Soup's particle filter with a constant-velocity model over each reading (the true sigma), begun on the
    first reading's line of bearing with the watch's range prior; its RMS after SETTLE_S and cost per reading."""
    from stonesoup.models.measurement.nonlinear import Cartesian2DToBearing
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.particle import ParticlePredictor
    from stonesoup.resampler.particle import ESSResampler
    from stonesoup.types.array import StateVectors
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import ParticleState
    from stonesoup.updater.particle import ParticleUpdater

    from aoa_localizer.engine.inference.motion import RANGE_M

    sc = data.scenario
    speed = max(sc.emitter_speed, 0.5)
    rng = np.random.default_rng(seed)
    truth, sensor = data.emitter_at(data.bearings[:, 0]), data.sensor_enu
    theta = np.radians(90.0 - data.bearings[:, 1])  # the readings as ENU angles (near the datum: no convergence)
    motion = CombinedLinearGaussianTransitionModel([ConstantVelocity(2 * speed ** 2 / VELOCITY_TAU_S)] * 2)
    distance = np.exp(rng.uniform(*np.log(RANGE_M), PEER_PARTICLES))
    ray = theta[0] + 3 * data.sigma[0] * rng.standard_normal(PEER_PARTICLES)
    vectors = np.vstack([sensor[0, 0] + distance * np.cos(ray), speed * rng.standard_normal(PEER_PARTICLES),
                         sensor[0, 1] + distance * np.sin(ray), speed * rng.standard_normal(PEER_PARTICLES)])
    start = datetime(2026, 1, 1)
    state = ParticleState(StateVectors(vectors), weight=np.full(PEER_PARTICLES, 1.0 / PEER_PARTICLES),
                          timestamp=start + timedelta(seconds=float(data.bearings[0, 0])))
    predictor = ParticlePredictor(motion)
    err2 = []
    t0 = time.perf_counter()
    for k in range(1, len(theta)):
        when = start + timedelta(seconds=float(data.bearings[k, 0]))
        model = Cartesian2DToBearing(4, (0, 2), np.array([[data.sigma[k] ** 2]]),
                                     translation_offset=np.array([[sensor[k, 0]], [sensor[k, 1]]]))
        updater = ParticleUpdater(model, resampler=ESSResampler())
        prediction = predictor.predict(state, timestamp=when)
        state = updater.update(SingleHypothesis(prediction, Detection(np.array([[theta[k]]]), timestamp=when,
                                                                      measurement_model=model)))
        if data.bearings[k, 0] > SETTLE_S:
            mean = np.asarray(state.mean, float).ravel()
            err2.append((mean[0] - truth[k, 0]) ** 2 + (mean[2] - truth[k, 1]) ** 2)
    return {"peer_err2": float(np.mean(err2)), "peer_us": 1e6 * (time.perf_counter() - t0) / len(theta)}


def static_run(job: tuple[str, int]) -> tuple[str, float, bool, float]:
    logging.getLogger("aoa_localizer").setLevel(logging.ERROR)
    name, seed = job
    data = simulate(STATIC[name], seed)
    ests = [e for e in Localizer(scenario_config(data, LocalizerConfig(seed=1000 + seed))).run(data.inputs())
            if e is not None]
    last = ests[-1]
    p = last.motion_probability
    return name, p, last.motion == "static" and p <= 0.05, float(np.mean([e.motion != "static" for e in ests]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", nargs="*", default=list(MOVING))
    ap.add_argument("--static", nargs="*", default=list(STATIC))
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-peer", action="store_true", help="leave out Stone Soup's particle filter")
    args = ap.parse_args()
    with multiprocessing.Pool(args.jobs) as pool:
        moving = pool.map(moving_run, [(c, r, not args.no_peer) for c in args.cells for r in range(args.runs)])
        static = pool.map(static_run, [(c, r) for c in args.static for r in range(args.runs)])
    if args.cells:
        print("| cell | RMS / PCRB | RMS (m) | PCRB (m) | median error / median PCRB | in 95 % | published moving "
              "| p >= 0.9 after (s, median) | us/reading | Stone Soup PF RMS (m) | its us/reading |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
    for c in args.cells:
        r = [x for x in moving if x["name"] == c]
        rms, pcrb = math.sqrt(np.mean([x["err2"] for x in r])), math.sqrt(np.mean([x["bound2"] for x in r]))
        peer = (f"{math.sqrt(np.mean([x['peer_err2'] for x in r])):.0f} | {np.mean([x['peer_us'] for x in r]):.0f}"
                if "peer_err2" in r[0] else "- | -")
        median = np.median([x["median"] for x in r]) / np.median([x["bound_median"] for x in r])
        print(f"| {c} | {rms / pcrb:.2f} | {rms:.0f} | {pcrb:.0f} | {median:.2f} | "
              f"{100 * np.mean([x['in95'] for x in r]):.0f} % | {100 * np.mean([x['moving'] for x in r]):.0f} % | "
              f"{np.median([x['to_sure'] for x in r]):.0f} | {np.mean([x['us_per_reading'] for x in r]):.0f} | "
              f"{peer} |")
    if args.static:
        print("\n| static cell | median final p(moving) | final static, p(static) >= 0.95 | estimates not static |")
        print("|---|---|---|---|")
    for c in args.static:
        r = [x for x in static if x[0] == c]
        print(f"| {c} | {np.median([x[1] for x in r]):.3f} | {sum(x[2] for x in r)}/{len(r)} | "
              f"{100 * np.mean([x[3] for x in r]):.1f} % |")


if __name__ == "__main__":
    main()
