"""The survey model on cells of our own design: is it honest at 50 % and 95 %, sharp, and as good as least squares?

    python scripts/pooled_cells.py [--cells observer anchors anchor_medians hand_held] [--runs 4] [--seed 0]
                                   [--scale 1] [--receiver-class unknown]

Cells (aoa_localizer.simulation.surveys): `observer` one walking observer, 27 transmitters, built to reproduce
observer A's real survey (a common bias, an apparent place per transmitter, 8 deg visible scatter, 8 % wild);
`anchors` four indoor angle-of-arrival anchors heard at 16 places, 250 readings each with a steady bias per
anchor and place; `anchor_medians` the same with one median bearing per anchor and place; `hand_held` the round-3
survey benchmark's surveys (independent 20-30 deg noise, a bias per survey), 60 to a file. `--scale` multiplies
the layout (0.01: a room's bearings on a table; 100: across a county). Each run is one file through
`locate_pooled` with its defaults; the figures pool every emitter of every run.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from matplotlib.path import Path as MplPath

from aoa_localizer.engine.crlb import inside_ellipse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.site_bearings import least_squares_fix
from aoa_localizer.pooled import SurveyReading, locate_pooled
from aoa_localizer.pooled.region import ELLIPSE_50
from aoa_localizer.simulation.surveys import SurveySet, hand_held_set, indoor_anchors, observer_like

FRAME = LocalFrame(44.0, 7.0)
CELLS = {
    "observer": observer_like,
    "anchors": indoor_anchors,
    "anchor_medians": lambda rng: indoor_anchors(rng, summarise=True),
    "hand_held": hand_held_set,
}


def readings(data: SurveySet, scale: float) -> list[SurveyReading]:
    lat, lon, _ = FRAME.to_geodetic(data.places[:, 0] * scale, data.places[:, 1] * scale)
    return [SurveyReading(e, float(a), float(o), float(z), s)
            for e, s, a, o, z in zip(data.emitter, data.station, lat, lon, data.azimuth_deg, strict=True)]


def score(data: SurveySet, scale: float, receiver_class: str) -> tuple[list[tuple], float]:
    """Per emitter (error, least squares' error, in 50, in 95, in region 50, in region 95, sharpness), and the
    run's seconds."""
    t0 = time.perf_counter()
    res = locate_pooled(readings(data, scale), receiver_class)
    took = time.perf_counter() - t0
    emitter = np.array(data.emitter)
    out = []
    for e, fix in res.fixes.items():
        truth = data.truth[e] * scale
        err = np.array(FRAME.to_enu(fix.lat, fix.lon)) - truth
        mine = emitter == e
        ls = least_squares_fix(data.places[mine] * scale, data.azimuth_deg[mine])
        t_lat, t_lon, _ = FRAME.to_geodetic(*truth)
        inside = {lvl: any(MplPath(r[:, ::-1]).contains_point((t_lon, t_lat)) for r in fix.hpd[lvl])
                  for lvl in (0.5, 0.95)}
        d = float(np.hypot(*err))
        out.append((d / scale, float(np.hypot(*(ls - truth))) / scale if ls is not None else np.inf,
                    inside_ellipse(err, fix.cov, ELLIPSE_50), inside_ellipse(err, fix.cov), inside[0.5],
                    inside[0.95], fix.semi_axes()[0] / max(d, 1e-12)))
    return out, took


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", nargs="+", default=list(CELLS), choices=list(CELLS))
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--receiver-class", default="unknown")
    args = ap.parse_args(argv)
    print(f"scale x{args.scale:g}, receiver class {args.receiver_class}, {args.runs} runs a cell (seeds "
          f"{args.seed}-{args.seed + args.runs - 1}); errors in the unscaled layout's metres")
    print(f"{'cell':<15} {'n':>4} {'error':>8} {'l.sq.':>8} {'ell 50':>7} {'ell 95':>7} {'reg 50':>7} {'reg 95':>7} "
          f"{'sharp':>6} {'s/run':>6}")
    for name in args.cells:
        rows, secs = [], []
        for run in range(args.runs):
            got, took = score(CELLS[name](np.random.default_rng(args.seed + run)), args.scale, args.receiver_class)
            rows += got
            secs.append(took)
        a = np.array(rows, float)
        print(f"{name:<15} {len(a):>4} {np.median(a[:, 0]):8.3g} {np.median(a[:, 1]):8.3g} "
              + " ".join(f"{100 * a[:, i].mean():6.0f}%" for i in range(2, 6))
              + f" {np.median(a[:, 6]):6.2f} {np.median(secs):6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
