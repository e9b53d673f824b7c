"""Stopped = moving: every public scenario and robustness cell run once with the vehicle moving and once stopped at
each point (aoa_localizer.simulation.stops: the point's readings from one place, two fixes there around them).

    python scripts/stop_and_go.py [--cells seed urban wild20 ...] [--runs 20] [--jobs 2]

Per cell and form: RMS error over the RMS CRLB of the inlier readings, the truth inside the 95 % ellipse, how
many runs ended on the survey model, and how many stopped runs ended `tracking` with the truth outside the ellipse.
Defaults throughout (data seed r, filter seed 1000 + r).
"""
from __future__ import annotations

import argparse
import logging
import math
import multiprocessing

import numpy as np

from aoa_localizer import LocalizerConfig
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import SCENARIOS, robustness_cells, simulate
from aoa_localizer.simulation.stops import stopped

CELLS = {**SCENARIOS, **robustness_cells()}


def one(job: tuple[str, str, int]) -> tuple[str, str, float, float, bool, bool, bool]:
    logging.getLogger("aoa_localizer").setLevel(logging.ERROR)
    name, form, seed = job
    data = simulate(CELLS[name], seed)
    result = run(stopped(data) if form == "stopped" else data, LocalizerConfig(seed=1000 + seed))
    s = result.scores
    last = result.estimates[-1] if result.estimates else None
    survey = last is not None and last.algorithm == "survey"
    inside = bool(s.get("inside95", False))
    wrong = last is not None and last.state.value == "tracking" and not inside
    return name, form, s.get("error", math.inf), s["crlb"], inside, survey, wrong


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", nargs="+", default=list(CELLS))
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    jobs = [(c, f, r) for c in args.cells for f in ("moving", "stopped") for r in range(args.runs)]
    with multiprocessing.Pool(args.jobs) as pool:
        rows = pool.map(one, jobs)
    print("| cell | moving RMS / CRLB | stopped RMS / CRLB | moving in 95 % | stopped in 95 % | stopped on survey "
          "| stopped tracking outside |")
    print("|---|---|---|---|---|---|---|")
    for c in args.cells:
        got = {}
        for f in ("moving", "stopped"):
            r = [row for row in rows if row[0] == c and row[1] == f]
            err, bound = np.array([x[2] for x in r]), np.array([x[3] for x in r])
            got[f] = (math.sqrt(np.mean(err**2) / np.mean(bound**2)), np.mean([x[4] for x in r]),
                      sum(x[5] for x in r), sum(x[6] for x in r))
        m, s = got["moving"], got["stopped"]
        print(f"| {c} | {m[0]:.2f} | {s[0]:.2f} | {100 * m[1]:.0f} % | {100 * s[1]:.0f} % | {s[2]}/{args.runs} | "
              f"{s[3]}/{args.runs} |", flush=True)


if __name__ == "__main__":
    main()
