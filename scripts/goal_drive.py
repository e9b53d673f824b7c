"""Where to drive next, measured: time and distance until the 95 % ellipse's semi-major axis is under 50 m, for a
vehicle that follows `emitter/next_goal` against one that keeps to a fixed route, from the same start.

    python scripts/goal_drive.py [--runs 20] [--sigma-deg 1.1 5] [--jobs 2]

Routes (start (0, 0), emitter at the `homing` scenario's (1500, 1500), stop-and-go every ~50 m at 10 m/s):
* `homing`: the homing scenario's drive (straight at the emitter, then a dog-leg past it);
* `straight`: a straight road east, passing 1500 m south of the emitter;
* `goal after homing` / `goal after straight`: that route until the localizer has an estimate, then the goal
  (simulation.goal_drive.GoalDrive, engine.outputs.next_goal; goal radius 500 m, refreshed at every stop, about
  every 8 s).
Default configuration; each run's data seed is the same for all routes. A run that does not get there within
MAX_LEGS stops counts as not reached.
"""
from __future__ import annotations

import argparse
import math
import statistics
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.crlb import ellipse_axes, inside_ellipse
from aoa_localizer.simulation.goal_drive import GoalDrive, closed_loop
from aoa_localizer.simulation.scenarios import SCENARIOS

TARGET_M = 50.0
RADIUS_M = 500.0
MAX_LEGS = 120
ROUTES = {"homing": SCENARIOS["homing"].track, "straight": ((0.0, 0.0), (6000.0, 0.0))}


def one_run(route: str, follow_goal: bool, sigma_deg: float, seed: int) -> dict:
    """One drive; when (time, distance) the ellipse got under TARGET_M, its error then, and whether the truth was
    inside the ellipse."""
    base = SCENARIOS["homing"]
    track = ROUTES[route]
    length = sum(math.dist(a, b) for a, b in zip(track, track[1:], strict=False))
    sc = replace(base, track=track, points=max(2, round(length / 50.0) + 1), sigma_rad=math.radians(sigma_deg))
    drive = GoalDrive(sc, seed)
    loc = Localizer(LocalizerConfig(seed=seed))
    for est in closed_loop(drive, loc, RADIUS_M, follow_goal):
        if est is not None and ellipse_axes(est.cov)[0] < TARGET_M:
            error = (sc.emitter[0] - est.east, sc.emitter[1] - est.north)
            loc.close()
            return {"reached": True, "time_s": drive.t, "distance_m": drive.odometer_m,
                    "error_m": math.hypot(*error), "inside": inside_ellipse(error, est.cov)}
        if drive.legs >= MAX_LEGS:
            break
    loc.close()
    return {"reached": False, "time_s": drive.t, "distance_m": drive.odometer_m}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--sigma-deg", type=float, nargs="+", default=[math.degrees(SCENARIOS["homing"].sigma_rad),
                                                                        5.0])
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    arms = [(route, goal) for route in ROUTES for goal in (False, True)]
    with ProcessPoolExecutor(args.jobs) as pool:
        for sigma in args.sigma_deg:
            print(f"\nbearing noise {sigma:.1f} deg, {args.runs} runs")
            print("| drive | reached | time to 50 m (median, s) | distance (median, m) | error then (median, m) "
                  "| truth in ellipse |")
            print("|---|---|---|---|---|---|")
            for route, goal in arms:
                jobs = [pool.submit(one_run, route, goal, sigma, seed) for seed in range(args.runs)]
                res = [j.result() for j in jobs]
                hit = [r for r in res if r["reached"]]
                name = f"goal after {route}" if goal else route
                if not hit:
                    print(f"| {name} | 0/{len(res)} | - | - | - | - |")
                    continue
                print(f"| {name} | {len(hit)}/{len(res)} | {statistics.median(r['time_s'] for r in hit):.0f} | "
                      f"{statistics.median(r['distance_m'] for r in hit):.0f} | "
                      f"{statistics.median(r['error_m'] for r in hit):.1f} | "
                      f"{sum(r['inside'] for r in hit)}/{len(hit)} |")


if __name__ == "__main__":
    main()
