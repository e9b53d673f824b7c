"""Hand-held surveys with the default configuration: an estimate for every transmitter, its median error against
plain least-squares triangulation's on the same bearings, and how often the truth is inside the 95 % ellipse.

    .venv/bin/python scripts/survey_benchmark.py --runs 60 --seed 1
"""
import argparse

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import ellipse_axes, inside_ellipse
from aoa_localizer.engine.surveys import hand_held, least_squares_fix, locate_survey


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=60, help="surveys (default 60)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the simulated surveys")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                        help="a LocalizerConfig change (e.g. noise=fixed); values are read as floats where they parse")
    args = parser.parse_args(argv)
    changes = {}
    for item in args.param:
        name, _, text = item.partition("=")
        try:
            changes[name] = float(text)
        except ValueError:
            changes[name] = text
    rng = np.random.default_rng(args.seed)
    errors, ls, inside, sizes, missing = [], [], 0, [], 0
    for i in range(args.runs):
        survey = hand_held(rng)
        fix = least_squares_fix(survey.stations, survey.azimuth_deg)
        ls.append(np.inf if fix is None else float(np.hypot(*fix)))
        est = locate_survey(survey, LocalizerConfig(seed=i).with_changes(**changes))
        if est is None:
            missing += 1
            continue
        err = np.array([est.east, est.north])
        errors.append(float(np.hypot(*err)))
        inside += inside_ellipse(err, est.cov)
        sizes.append(ellipse_axes(est.cov)[0])
    print(f"surveys {args.runs}: estimates {len(errors)} (none for {missing}); median error "
          f"{np.median(errors):.0f} m, least squares {np.median(ls):.0f} m; truth inside the 95 % ellipse "
          f"{inside} of {len(errors)} ({100 * inside / max(1, len(errors)):.0f} %); median semi-major "
          f"{np.median(sizes):.0f} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
