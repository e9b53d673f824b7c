"""Sparse surveys with the survey program's defaults (nothing about the receiver given).

Hand-held surveys (simulated): an estimate for every transmitter, its median error against plain least-squares
triangulation's on the same bearings, and how often the truth is inside the 95 % ellipse.

    .venv/bin/python scripts/survey_benchmark.py --runs 60 --seed 1

Lenth (1981), `examples/lenth1981.csv` (docs/lenth1981.md): the distance from the target over filter seeds, with
all 8 readings and without the wild reading 6, beside the paper's estimators.

    .venv/bin/python scripts/survey_benchmark.py --lenth 20
"""
import argparse
from pathlib import Path

import numpy as np

from aoa_localizer.common.cli import param_changes
from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.crlb import ellipse_axes, inside_ellipse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.site_bearings import least_squares_fix, survey_config
from aoa_localizer.simulation.surveys import hand_held, locate_survey
from aoa_localizer.tools.locate import locate, read_rows

LENTH_CSV = Path(__file__).resolve().parent.parent / "examples" / "lenth1981.csv"
LENTH_TARGET_M = np.array([7502.0, 2198.0])  # from the paper's Table 2 distances, km east and north of the datum
LENTH_DATUM = (46.5, -84.3)


def hand_held_surveys(runs: int, seed: int, changes: dict):
    rng = np.random.default_rng(seed)
    errors, ls, inside, sizes, missing = [], [], 0, [], 0
    for i in range(runs):
        survey = hand_held(rng)
        fix = least_squares_fix(survey.stations, survey.azimuth_deg)
        ls.append(np.inf if fix is None else float(np.hypot(*fix)))
        est = locate_survey(survey, survey_config(seed=i, **changes))
        if est is None:
            missing += 1
            continue
        err = np.array([est.east, est.north])
        errors.append(float(np.hypot(*err)))
        inside += inside_ellipse(err, est.cov)
        sizes.append(ellipse_axes(est.cov)[0])
    print(f"surveys {runs}: estimates {len(errors)} (none for {missing}); median error "
          f"{np.median(errors):.0f} m, least squares {np.median(ls):.0f} m; truth inside the 95 % ellipse "
          f"{inside} of {len(errors)} ({100 * inside / max(1, len(errors)):.0f} %); median semi-major "
          f"{np.median(sizes):.0f} m")


def lenth(runs: int, changes: dict):
    rows, _ = read_rows(LENTH_CSV, None)
    frame = LocalFrame(*LENTH_DATUM, 0.0)
    for label, chosen in (("all 8 readings", rows), ("without reading 6", [r for r in rows if r.station != "obs6"])):
        dist, inside, axes = [], 0, []
        for seed in range(runs):
            est, _ = locate(chosen, survey_config(seed=seed, **changes), (chosen[0].lat, chosen[0].lon))
            if est is None:
                continue
            e, n = frame.to_enu(est.lat, est.lon)
            err = np.array([float(e), float(n)]) - LENTH_TARGET_M
            dist.append(float(np.hypot(*err)) / 1000.0)
            inside += inside_ellipse(err, est.cov)
            axes.append(ellipse_axes(est.cov)[:2])
        a, b = np.median(axes, axis=0)
        print(f"Lenth, {label}: {len(dist)} of {runs} seeds with an estimate; distance from the target median "
              f"{np.median(dist):.3f} km (range {min(dist):.3f}-{max(dist):.3f}); target inside the 95 % ellipse "
              f"{inside} of {len(dist)}; median semi-axes {a:.0f} x {b:.0f} m")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=60, help="surveys (default 60)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the simulated surveys")
    parser.add_argument("--lenth", type=int, metavar="SEEDS", help="run Lenth's example over this many seeds instead")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                        help="a LocalizerConfig change (e.g. noise=fixed), as the programs' -p")
    args = parser.parse_args(argv)
    try:
        changes = param_changes(args.param)
        survey_config(**changes)
    except ConfigError as exc:
        parser.error(str(exc))
    if args.lenth:
        lenth(args.lenth, changes)
    else:
        hand_held_surveys(args.runs, args.seed, changes)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
