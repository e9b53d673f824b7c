"""Bearings from a DF array mounted on the vehicle, turned by the course over ground of noisy GPS: is the estimate
near the emitter, and does its 95 % ellipse hold the truth?

    python scripts/relative_bearings.py [--gps-noise 0 3] [--mount 30] [--seeds 1 2 3 4]

The simulator's array reads azimuths from the vehicle's forward axis (`scenarios.mounted`); the localizer reads them
with the matching settings (`scenarios.receiver_settings`) and otherwise its default configuration. The CRLB is the
receiver's alone (a known heading); the course's noise comes on top of it.
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from aoa_localizer import LocalizerConfig
from aoa_localizer.engine.crlb import ellipse_axes
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import SCENARIOS, mounted, receiver_settings, simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gps-noise", type=float, nargs="+", default=[0.0, 3.0], metavar="M",
                        help="white GPS noise per fix and axis (m)")
    parser.add_argument("--mount", type=float, default=30.0, metavar="DEG", help="the array's mount offset")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4], metavar="N", help="data seeds")
    parser.add_argument("--scenarios", nargs="+", default=["seed", "homing", "urban"], choices=sorted(SCENARIOS))
    args = parser.parse_args()
    print("| GPS noise | scenario | errors (m) | error / CRLB, median | 95 % ellipse semi-axes (m), median | "
          "truth inside | NEES, mean | states | heading_unknown |")
    print("|---|---|---|---|---|---|---|---|---|")
    for noise in args.gps_noise:
        for name in args.scenarios:
            sc = mounted(replace(SCENARIOS[name], gps_noise_m=noise), args.mount)
            rows = []
            for seed in args.seeds:
                res = run(simulate(sc, seed), LocalizerConfig(seed=seed).with_changes(**receiver_settings(args.mount)))
                refused = res.localizer.view(light=True).rejected["heading_unknown"]
                if not res.estimates:  # scored as infinitely far, outside, in a state of its own
                    no_estimate = {"error": np.inf, "crlb": res.scores["crlb"], "inside95": False, "nees": np.inf}
                    rows.append((no_estimate, "no estimate", np.array([np.inf, np.inf]), refused))
                    continue
                est = res.estimates[-1]
                rows.append((res.scores, est.state, ellipse_axes(est.cov)[:2], refused))
            errors = [s["error"] for s, *_ in rows]
            ratio = float(np.median([s["error"] / s["crlb"] for s, *_ in rows]))
            axes = np.median([a for _, _, a, _ in rows], axis=0)
            inside = sum(bool(s["inside95"]) for s, *_ in rows)
            nees = float(np.mean([s["nees"] for s, *_ in rows]))
            states = ", ".join(sorted({st for _, st, _, _ in rows}))
            low, high = min(r for *_, r in rows), max(r for *_, r in rows)
            refused = f"{low}" if low == high else f"{low}-{high}"
            print(f"| {noise:g} m | {name} | {', '.join(f'{e:.1f}' for e in errors)} | {ratio:.1f}x | "
                  f"{axes[0]:.1f} x {axes[1]:.1f} | {inside} of {len(rows)} | {nees:.2f} | {states} | {refused} |",
                  flush=True)


if __name__ == "__main__":
    main()
