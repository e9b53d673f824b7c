"""The survey model against the Cramer-Rao bound on surveys with independent Gaussian noise (no site error).

    python scripts/survey_bound.py [--sigmas 0.2 1 5] [--stations 3 10 50 200] [--layouts 10 1000 20000]
                                   [--readings 1] [--ids 1] [--network] [--runs 20]

Each run: `--ids` transmitters placed uniformly in a square of the layout's size, each heard from `--stations`
stations 0.5-1 layout away in uniform directions (`--network`: the same stations, 0.5-1 layout from the square's
centre, hear every transmitter: fixed sites), `--readings` readings a station with noise N(0, sigma); one file
through `locate_pooled` with its defaults. Per cell: RMS error over the RMS CRLB, the truth inside the 95 % and
50 % covariance ellipses, and the median sharpness (95 % semi-major over the error).
"""
from __future__ import annotations

import argparse
import itertools
import math
import time

import numpy as np

from aoa_localizer.engine.crlb import ELLIPSE_50, crlb_rmse, ellipse_axes, inside_ellipse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.pooled import SurveyReading, locate_pooled

FRAME = LocalFrame(44.0, 7.0)


def ring(rng: np.random.Generator, centre: np.ndarray, stations: int, layout: float) -> np.ndarray:
    """Station places (K, 2) 0.5-1 layout from `centre` in uniform directions."""
    ang = rng.uniform(0, 2 * math.pi, stations)
    rr = rng.uniform(0.5, 1.0, stations) * layout
    return centre + np.column_stack([rr * np.sin(ang), rr * np.cos(ang)])


def one_run(rng: np.random.Generator, sigma_deg: float, stations: int, layout: float, readings: int,
            ids: int, network: bool = False) -> list[tuple[float, float, bool, bool, float]]:
    """Per transmitter: (error, CRLB, in 95, in 50, 95 % semi-major)."""
    rows, truth, places = [], {}, {}
    masts = ring(rng, np.zeros(2), stations, layout) if network else None
    for e in range(ids):
        t = rng.uniform(-0.5, 0.5, 2) * layout
        st = masts if masts is not None else ring(rng, t, stations, layout)
        truth[str(e)], places[str(e)] = t, st
        lat, lon, _ = FRAME.to_geodetic(st[:, 0], st[:, 1])
        north = FRAME.north_angle(lat, lon)  # each station's true north in the plane (meridians converge)
        for k in range(stations):
            az = math.degrees(north[k] - math.atan2(t[1] - st[k, 1], t[0] - st[k, 0]))
            for _ in range(readings):
                rows.append(SurveyReading(str(e), float(lat[k]), float(lon[k]), az + rng.normal(0.0, sigma_deg),
                                          f"m{k}" if network else f"s{e}_{k}"))
    out = []
    for e, fix in locate_pooled(rows).fixes.items():
        err = np.array(FRAME.to_enu(fix.lat, fix.lon)) - truth[e]
        bound = crlb_rmse(truth[e], places[e], np.full(stations, math.radians(sigma_deg) / math.sqrt(readings)))
        out.append((float(np.hypot(*err)), bound, inside_ellipse(err, fix.cov),
                    inside_ellipse(err, fix.cov, ELLIPSE_50), ellipse_axes(fix.cov)[0]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0.2, 1.0, 5.0])
    ap.add_argument("--stations", type=int, nargs="+", default=[3, 10, 50, 200])
    ap.add_argument("--layouts", type=float, nargs="+", default=[10.0, 1000.0, 20000.0])
    ap.add_argument("--readings", type=int, nargs="+", default=[1])
    ap.add_argument("--ids", type=int, default=1)
    ap.add_argument("--network", action="store_true", help="the same fixed stations hear every transmitter")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    kind = "network" if args.network else "own"
    print("| sigma deg | stations | readings | layout m | ids | stations of | RMS / CRLB | in 95 % | in 50 % "
          "| sharpness | s/run |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for sigma, k, n, layout in itertools.product(args.sigmas, args.stations, args.readings, args.layouts):
        rng = np.random.default_rng(args.seed)
        t0 = time.perf_counter()
        r = np.array([row for _ in range(args.runs)
                      for row in one_run(rng, sigma, k, layout, n, args.ids, args.network)], float)
        took = (time.perf_counter() - t0) / args.runs
        ratio = math.sqrt(np.mean(r[:, 0] ** 2) / np.mean(r[:, 1] ** 2))
        sharp = float(np.median(r[:, 4] / np.maximum(r[:, 0], 1e-12)))
        print(f"| {sigma:g} | {k} | {n} | {layout:g} | {args.ids} | {kind} | {ratio:.2f} | "
              f"{100 * r[:, 2].mean():.0f} % | {100 * r[:, 3].mean():.0f} % | {sharp:.1f} | {took:.2f} |", flush=True)


if __name__ == "__main__":
    main()
