"""What a compiled kernel would gain on the hot path: the latent noise's log densities of places x points x
hypotheses (global_search.latent_log_densities), numpy against a numba loop that makes the same numbers.

    python scripts/kernel_gain.py      (numba from the `bench` extra; nothing here is a test or a runtime path)

The kernel makes each point's residual once, each distinct scale's Gaussian once (as the numpy code does) and a log
per hypothesis, in one pass without temporaries; it is checked against the numpy code (1e-9 rad^-1 in log density)
before it is timed. Each figure is the fastest of five timed loops. docs/design.md has the decision it informs.
"""
import argparse
import math
import sys
import time
import timeit

import numpy as np

from aoa_localizer.engine.inference.global_search import Points, Robust, latent_log_densities
from aoa_localizer.engine.inference.receiver import NoiseGrid

try:
    import numba
except ImportError:  # the `bench` extra is not installed
    numba = None

TWO_PI = 2.0 * math.pi
# (places, points): a start search's refinement at a few dozen points, a cloud's look, a long drive, a
# provisional sample's draws
SIZES = ((1, 60), (6, 60), (100, 60), (6, 240), (100, 300), (2000, 20))


def kernel_source(x, east, north, cos, sin, sigma2, gps_var, distinct, which, outlier, widen2):
    """sum_k log p(resid_k | h) per place and hypothesis, (M, H), as latent_log_densities makes it."""
    m, k, h, d = x.shape[0], east.shape[0], which.shape[0], distinct.shape[0]
    out = np.zeros((m, h))
    g = np.empty(d)
    for i in range(m):
        for j in range(k):
            dx = x[i, 0] - east[j]
            dy = x[i, 1] - north[j]
            r = math.atan2(dx * sin[j] - dy * cos[j], dx * cos[j] + dy * sin[j])
            extra = widen2 + gps_var[j] / max(dx * dx + dy * dy, 1.0)
            for q in range(d):
                v = distinct[q] * distinct[q] * sigma2[j] + extra
                g[q] = math.exp(-0.5 * r * r / v) / math.sqrt(TWO_PI * v)
            for q in range(h):
                out[i, q] += math.log((1.0 - outlier[q]) * g[which[q]] + outlier[q] / TWO_PI)
    return out


def fastest_us(call, reps: int) -> float:
    """The fastest of five loops of `reps` calls, per call (microseconds)."""
    return min(timeit.repeat(call, number=reps, repeat=5)) / reps * 1e6


def main(argv=None) -> int:
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    if numba is None:
        print("kernel_gain: numba is not installed (pip install -e '.[bench]')", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    kernel = numba.njit(fastmath=True)(kernel_source)
    rng = np.random.default_rng(0)
    grid = NoiseGrid.weak(1.1)
    rob = Robust(0.05, 3.0, grid=grid)
    compiled = None
    print("| places | points | hypotheses | numpy (us) | numba (us) | numpy / numba | max difference |")
    print("|---|---|---|---|---|---|---|")
    for m, k in SIZES:
        pts = Points(rng.normal(0, 300, k), rng.normal(0, 300, k), rng.uniform(-np.pi, np.pi, k), np.full(k, 0.02))
        x = rng.normal(500, 300, (m, 2))
        args = (x, pts.east, pts.north, pts.cos, pts.sin, pts.sigma**2, pts.gps_var(rob) * np.ones(k),
                grid.distinct[0], grid.distinct[1], grid.outlier, 0.0)
        diff = float(np.max(np.abs(latent_log_densities(x, pts, rob) - kernel(*args))))
        if compiled is None:
            compiled = time.perf_counter() - t0
        if diff > 1e-9 * k:
            print(f"kernel_gain: the kernel differs from numpy by {diff:.1e} at {m} x {k}", file=sys.stderr)
            return 1
        reps = max(1, 20000 // (m * k))
        ours = fastest_us(lambda x=x, pts=pts: latent_log_densities(x, pts, rob), reps)
        theirs = fastest_us(lambda args=args: kernel(*args), reps)
        print(f"| {m} | {k} | {grid.scale.size} | {ours:.1f} | {theirs:.1f} | {ours / theirs:.2f} | {diff:.1e} |")
    print(f"\nnumba {numba.__version__}, numpy {np.__version__}; first call (compilation) {compiled:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
