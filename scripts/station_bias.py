"""Fixed stations whose bearings carry a steady bias: does the ellipse stop shrinking where the biases bind?

    python scripts/station_bias.py [--runs 40] [--counts 1 10 100 1000] [--bias-deg 5] [--sigma-deg 2] [--seed 0]

Each run: one emitter, 4-6 stations around it at 0.5-3 km, each with its own bias N(0, bias) held for all its
readings and reading noise N(0, sigma); the same biases at every reading count, so only the count changes. The
readings go through the pooled survey model with its defaults (aoa_localizer.pooled, what `locate` runs). Prints,
per count, the truth inside the 50 % and 95 % ellipses, the median 95 % semi-major and the median error.
"""
from __future__ import annotations

import argparse
import math

import numpy as np

from aoa_localizer.engine.crlb import inside_ellipse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.pooled import SurveyReading, locate_pooled
from aoa_localizer.pooled.region import ELLIPSE_50

FRAME = LocalFrame(52.0, 5.0)


def run(rng: np.random.Generator, counts: list[int], bias_deg: float, sigma_deg: float) -> list[tuple]:
    """One layout and its biases, located at each reading count: (error m, inside 50, inside 95, semi-major m)."""
    truth = rng.uniform(-1000, 1000, 2)
    k = int(rng.integers(4, 7))
    ang = np.sort(rng.uniform(0, 2 * math.pi, k))
    rng_m = rng.uniform(500, 3000, k)
    stations = truth + np.column_stack([rng_m * np.sin(ang), rng_m * np.cos(ang)])
    bias = rng.normal(0, bias_deg, k)
    noise = rng.standard_normal((k, max(counts)))
    out = []
    for n in counts:
        readings = []
        for i, (e, north) in enumerate(stations):
            lat, lon, _ = FRAME.to_geodetic(e, north)
            true_az = math.degrees(math.atan2(truth[0] - e, truth[1] - north))
            readings += [SurveyReading("x", lat, lon, (true_az + bias[i] + sigma_deg * z) % 360, f"s{i}")
                         for z in noise[i, :n]]
        fix = locate_pooled(readings).fixes["x"]
        err = np.array(FRAME.to_enu(fix.lat, fix.lon)) - truth
        out.append((float(np.hypot(*err)), inside_ellipse(err, fix.cov, ELLIPSE_50), inside_ellipse(err, fix.cov),
                    fix.semi_axes()[0]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--counts", type=int, nargs="+", default=[1, 10, 100, 1000])
    ap.add_argument("--bias-deg", type=float, default=5.0)
    ap.add_argument("--sigma-deg", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rows = [run(rng, args.counts, args.bias_deg, args.sigma_deg) for _ in range(args.runs)]
    print(f"{args.runs} runs, station bias N(0, {args.bias_deg:g} deg), reading sigma {args.sigma_deg:g} deg")
    print(f"{'readings':>9} {'in 50 %':>8} {'in 95 %':>8} {'semi-major 95 % (m)':>20} {'error (m)':>10}")
    for j, n in enumerate(args.counts):
        err, in50, in95, a95 = (np.array([r[j][i] for r in rows]) for i in range(4))
        print(f"{n:>9} {100 * in50.mean():7.0f}% {100 * in95.mean():7.0f}% {np.median(a95):20.0f} "
              f"{np.median(err):10.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
