"""One receiver over its channels: does a channel heard briefly gain from the others' calibration (issue 50)?

    python scripts/receiver_pool.py [--runs 20] [--noise-x 0.33 3] [--share 0.1] [--seed 0]

Each run: the `seed` drive with a receiver whose bearing noise is `--noise-x` times the configured sigma, one
transmitter heard the whole drive, a second only over the last `--share` of it (about 6 points: too few readings
to calibrate its own noise). The run goes through one Localizer with the receiver pool (receiver_pool.py) and
without it (each channel's own weak prior). Prints, for the second transmitter's final estimate: the truth inside
its 95 % ellipse, the median error, 95 % semi-major and sharpness (semi-major over error), and the pool's scale.
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from aoa_localizer.engine import channels
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import ellipse_axes, inside_ellipse
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.simulation.fleet import simulate_fleet
from aoa_localizer.simulation.scenarios import SCENARIOS

FIRST, BRIEF = 433.92e6, 446.0e6
EMITTERS = {FIRST: (1200.0, 800.0), BRIEF: (400.0, 1100.0)}


def one_run(seed: int, noise_x: float, share: float) -> tuple | None:
    """The brief transmitter's final estimate: (error m, inside 95 %, semi-major m, pooled scale or None)."""
    sc = replace(SCENARIOS["seed"], sigma_rad=noise_x * SCENARIOS["seed"].sigma_rad)
    data = simulate_fleet({"": sc}, EMITTERS, seed)
    stamps = np.array([b[0] for b in data.bearings[""]])
    cut = stamps.min() + (1.0 - share) * np.ptp(stamps)
    heard = [b for b in data.bearings[""] if b[3] == FIRST or b[0] >= cut]
    events = [("fix", f) for f in data.fixes[""]] + [("df", b) for b in heard]
    loc = Localizer(LocalizerConfig(seed=seed))
    for kind, row in sorted(events, key=lambda e: e[1][0]):
        if kind == "fix":
            loc.add_fix(*row[:4])
        else:
            loc.add_bearing(row[0], row[1], row[2], frequency_hz=row[3])
    loc.flush()
    loc.finish()
    loc.close()
    channel = loc._channel(channels.channel_id(BRIEF))  # its survey start (pooled_start) is the engine's own
    if channel is None or channel.estimate is None:
        return None
    est = channel.estimate
    err = np.array(LocalFrame(*sc.datum).to_enu(est.lat, est.lon)) - np.array(EMITTERS[BRIEF])
    pooled = channel.pooled_start
    return float(np.hypot(*err)), bool(inside_ellipse(err, est.ground_cov)), ellipse_axes(est.ground_cov)[0], \
        pooled.scale if pooled else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--noise-x", type=float, nargs="+", default=[0.33, 3.0])
    ap.add_argument("--share", type=float, default=0.1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    pool = channels.Channels.pooled_noise
    print("| noise x configured | pool | estimates | inside 95 % | median error (m) | median 95 % semi-major (m) | "
          "median sharpness | pooled scale |\n|---|---|---|---|---|---|---|---|")
    for noise_x in args.noise_x:
        for pooled in (False, True):
            channels.Channels.pooled_noise = pool if pooled else (lambda self, but=None: None)  # type: ignore[method-assign]
            got = [r for r in (one_run(args.seed + k, noise_x, args.share) for k in range(args.runs)) if r]
            scales = [r[3] for r in got if r[3] is not None]
            scale = f"{np.median(scales):.2f}" if scales else "-"
            print(f"| {noise_x:g} | {'on' if pooled else 'off'} | {len(got)} of {args.runs} | "
                  f"{sum(r[1] for r in got)} | {np.median([r[0] for r in got]):.1f} | "
                  f"{np.median([r[2] for r in got]):.0f} | {np.median([r[2] / r[0] for r in got]):.2f} | {scale} |",
                  flush=True)
    channels.Channels.pooled_noise = pool  # type: ignore[method-assign]


if __name__ == "__main__":
    main()
