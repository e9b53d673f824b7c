"""How real azimuth errors are shared within a collar: fit error models to surveys whose truth is known.

    python scripts/place_error_fit.py examples/real/telemetry_observer_a.csv \
        examples/real/telemetry_observer_a_truth.csv [more bearings/truth pairs ...]

For each pair of files, and for all of them together, each id's azimuth errors against its truth are taken as a
Gaussian vector: a common bias, an independent part tau^2 I, and either nothing more, a common rotation (the same
angle for every bearing of the id), a place-like part (lambda R)^2 J J^T (the bearings point at a place displaced
from the truth by lambda times its median range R; J the azimuths' derivative by the truth's place), or that
place-like part as a mixture of two scales. Prints each model's negative log likelihood at its maximum and its
parameters (docs/design.md, "Honest on real bearings", uses them for the hand-held class's prior).
"""
from __future__ import annotations

import argparse
import csv
import math
from collections import defaultdict

import numpy as np
from scipy.optimize import minimize

from aoa_localizer.engine.geodesy import LocalFrame

_LOG_2PI = math.log(2 * math.pi)


def collars(bearings: str, truth: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per id: its azimuth errors against the truth (rad) and J R, the errors' derivative by the truth's place
    times the median range."""
    with open(truth, newline="") as fh:
        where = {r["id"]: (float(r["lat"]), float(r["lon"])) for r in csv.DictReader(fh)}
    rows = defaultdict(list)
    with open(bearings, newline="") as fh:
        for r in csv.DictReader(fh):
            if r["id"] in where:
                rows[r["id"]].append((float(r["lat"]), float(r["lon"]), float(r["azimuth_deg"])))
    out = []
    for ident, mine in rows.items():
        frame = LocalFrame(*where[ident], 0.0)
        e, n = frame.to_enu(np.array([m[0] for m in mine]), np.array([m[1] for m in mine]))
        true_az = np.arctan2(-e, -n)
        err = (np.radians([m[2] for m in mine]) - true_az + math.pi) % (2 * math.pi) - math.pi
        r = np.hypot(e, n)
        jr = np.column_stack([np.cos(true_az), -np.sin(true_az)]) / r[:, None] * float(np.median(r))
        out.append((err, jr))
    return out


def _log_normal(r: np.ndarray, cov: np.ndarray) -> float:
    _, logdet = np.linalg.slogdet(cov)
    return -0.5 * float(r @ np.linalg.solve(cov, r) + logdet + r.size * _LOG_2PI)


def nll(x: np.ndarray, data: list, kind: str) -> float:
    """Negative log likelihood; x = log tau, log scale(s), bias, [logit of the first scale's weight]."""
    tau, bias = math.exp(x[0]), x[-1] if kind != "two" else x[3]
    total = 0.0
    for err, jr in data:
        r, eye = err - bias, np.eye(err.size) * tau**2
        if kind == "none":
            total -= _log_normal(r, eye)
        elif kind == "rotation":
            total -= _log_normal(r, eye + math.exp(x[1]) ** 2 * np.ones((err.size, err.size)))
        elif kind == "place":
            total -= _log_normal(r, eye + math.exp(x[1]) ** 2 * jr @ jr.T)
        else:
            w = 1.0 / (1.0 + math.exp(-x[4]))
            a = math.log(w) + _log_normal(r, eye + math.exp(x[1]) ** 2 * jr @ jr.T)
            b = math.log(1 - w) + _log_normal(r, eye + math.exp(x[2]) ** 2 * jr @ jr.T)
            total -= float(np.logaddexp(a, b))
    return total


STARTS = {
    "none": [[math.log(0.3), 0.0]],
    "rotation": [[math.log(0.3), math.log(0.2), 0.1], [math.log(0.1), math.log(0.3), 0.1]],
    "place": [[math.log(0.3), math.log(0.2), 0.1], [math.log(0.1), math.log(0.3), 0.1]],
    "two": [[math.log(0.2), math.log(0.15), math.log(0.5), 0.05, 0.0],
            [math.log(0.2), math.log(0.2), math.log(0.4), 0.0, 1.0]],
}


def fit(data: list, kind: str) -> str:
    best = min((minimize(nll, np.array(x0), args=(data, kind), method="Nelder-Mead",
                         options={"maxiter": 8000, "xatol": 1e-6, "fatol": 1e-6}) for x0 in STARTS[kind]),
               key=lambda r: r.fun)
    x, deg = best.x, math.degrees
    words = f"nll {best.fun:6.1f}  tau {deg(math.exp(x[0])):4.1f} deg"
    if kind == "rotation":
        words += f"  rotation sd {deg(math.exp(x[1])):.1f} deg"
    elif kind == "place":
        words += f"  lambda {math.exp(x[1]):.2f}"
    elif kind == "two":
        w = 1.0 / (1.0 + math.exp(-x[4]))
        words += f"  lambda {math.exp(x[1]):.2f} ({100 * w:.0f} %) or {math.exp(x[2]):.2f} ({100 * (1 - w):.0f} %)"
    bias = x[3] if kind == "two" else x[-1]
    return words + f"  bias {deg(bias):+.1f} deg"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="bearings and truth CSVs, in pairs")
    args = ap.parse_args(argv)
    if len(args.files) % 2:
        ap.error("give the files in pairs: bearings, then its truth")
    sets = {b: collars(b, t) for b, t in zip(args.files[::2], args.files[1::2], strict=True)}
    if len(sets) > 1:
        sets["all together"] = [c for data in list(sets.values()) for c in data]
    for name, data in sets.items():
        print(f"{name} ({len(data)} ids)")
        for kind in ("none", "rotation", "place", "two"):
            print(f"  {kind:9s} {fit(data, kind)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
