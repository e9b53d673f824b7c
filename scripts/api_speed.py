"""What a user pays per measurement through the public API, beside the `particles` IBIS step in the same run.

    python scripts/api_speed.py [--runs 10] [--scenario seed] [--scheduling realtime]

For each run of a scenario (a public one, a robustness cell, or `dense`: `urban`'s drive with a 20 Hz receiver and
10 Hz GPS, so 20 readings per point, without `urban`'s receiver calibration): every `add_fix` and `add_bearing` call
of the Localizer (default configuration, N = 100) is timed; a *measurement* is one observation point's worth of
calls (the fixes and readings up to the call that closed the point; a call that used several points, such as the
start with every buffered point, counts as that many measurements with an equal share each, so the mean is the total
time over the points). Reported: the median and mean of the time per measurement, the geodesy's share (LocalFrame
calls, timed separately), and the IBIS sampler's median and mean step on the same points (docs/benchmarks.md has the
figures). With `--scheduling realtime` the checks run in the worker process and, between calls (untimed, as a node's
idle time), the run waits for the worker and makes the owed move sweeps (Localizer.catch_up): the calls'
time is then what the thread that feeds the Localizer pays, and that idle work is reported beside it. One run is
made first and not timed, so neither side's first calls in the process (IBIS's first resample-move step takes about
half a second) count. Nothing here is a test: speed targets live in benchmarks.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import particles_peers  # noqa: E402

from aoa_localizer import Localizer, LocalizerConfig  # noqa: E402
from aoa_localizer.engine import geodesy  # noqa: E402
from aoa_localizer.simulation.evaluation import scenario_config  # noqa: E402
from aoa_localizer.simulation.scenarios import SCENARIOS, robustness_cells, simulate  # noqa: E402

logging.getLogger("aoa_localizer").setLevel(logging.ERROR)

CASES = {**SCENARIOS, **robustness_cells(),
         # urban's drive and receiver at 20 Hz with 10 Hz GPS, under the default configuration (no calibration given)
         "dense": replace(SCENARIOS["urban"], name="dense", df_rate_hz=20.0, gps_rate_hz=10.0, filter_overrides={})}


class GeodesyClock:
    """Wraps LocalFrame's methods to add up their time (the share of the per-call geodesy)."""

    def __init__(self):
        self.seconds = 0.0
        self.originals = {}

    def __enter__(self):
        for name in ("to_enu", "to_geodetic", "north_angle"):
            original = getattr(geodesy.LocalFrame, name)
            self.originals[name] = original

            def timed(frame, *args, _original=original, **kwargs):
                t0 = time.perf_counter()
                try:
                    return _original(frame, *args, **kwargs)
                finally:
                    self.seconds += time.perf_counter() - t0

            setattr(geodesy.LocalFrame, name, timed)
        return self

    def __exit__(self, *exc):
        for name, original in self.originals.items():
            setattr(geodesy.LocalFrame, name, original)


def one_run(scenario: str, r: int, scheduling: str):
    data = simulate(CASES[scenario], r)
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=10000 + r, scheduling=scheduling)))
    per_point, spent, points, idle = [], 0.0, 0, 0.0
    with GeodesyClock() as geo:
        for kind, row in data.events():
            t0 = time.perf_counter()
            if kind == "fix":
                loc.add_fix(row[0], row[1], row[2], row[3])
            else:
                loc.add_bearing(row[0], row[1], row[2])
            spent += time.perf_counter() - t0
            if scheduling == "realtime":
                t1 = time.perf_counter()
                loc.catch_up()  # the worker waited for and every owed move made
                idle += time.perf_counter() - t1
            now = loc.view(light=True).track.points_used
            if now > points:  # this call closed (and used) observation points: each costs its share
                per_point += [spent / (now - points)] * (now - points)
                spent, points = 0.0, now
            points = min(points, now)  # a re-start (the emitter moved) counts its points afresh
        geo_share = geo.seconds
    loc.close()
    total = sum(per_point)
    post = loc.posterior()
    pts, start = post.used_points, post.start_cloud
    mean, cov = start.mean(axis=0), 2.0 * np.cov(start.T)
    _, ibis_steps = particles_peers.run_ibis(pts, mean, cov, 100, loc.config.outlier_prob, 10000 + r)
    return per_point, geo_share / max(total, 1e-12), ibis_steps, idle / max(len(per_point), 1)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--scenario", choices=sorted(CASES), default="seed")
    parser.add_argument("--scheduling", choices=("reproducible", "realtime"), default="reproducible",
                        help="the Localizer's scheduling (reproducible: the Python API's default)")
    args = parser.parse_args(argv)
    if not particles_peers.AVAILABLE:
        print("the `particles` package is needed (pip install -e '.[bench]')", file=sys.stderr)
        return 2
    # One run first, untimed: IBIS's first resample-move step in a process takes about half a second (first calls),
    # and our worker's start and first calls cost too; counted, they swamped the means.
    one_run(args.scenario, args.runs, args.scheduling)
    ours, ibis, shares, idle = [], [], [], []
    for r in range(args.runs):
        per_point, share, steps, idle_per_point = one_run(args.scenario, r, args.scheduling)
        ours += per_point
        ibis += steps
        shares.append(share)
        idle.append(idle_per_point)
    o, i = 1e3 * np.array(ours), 1e3 * np.array(ibis)
    print(f"{args.scenario}, {args.runs} runs, N = 100, {args.scheduling}: per measurement through the API median "
          f"{np.median(o):.3f} ms, mean {o.mean():.3f} ms (geodesy {100 * np.mean(shares):.1f} % of it); "
          f"IBIS step median {np.median(i):.3f} ms, mean {i.mean():.3f} ms; "
          f"ratio of medians {np.median(o) / np.median(i):.2f}, of means {o.mean() / i.mean():.2f}"
          + (f"; idle work (owed moves) {1e3 * np.mean(idle):.3f} ms per measurement" if args.scheduling == "realtime"
             else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
