"""A constant bearing offset, learned where the data determine it: a mount offset left at 0, a forgotten magnetic
declination, a DF whose north is off. Every bearing then reads the same angle off; on a drive with turns no single
place explains them all, and the joint optimum of (place, offset) stands out from the place alone.

Offsets are ENU radians: the corrected bearing is the given one minus the offset, so a true azimuth is the read
azimuth plus the offset in degrees (ENU angles run the other way round).
"""
from __future__ import annotations

import math

import numpy as np

from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.global_search import Points, Robust, linearised, log_posterior

_STARTS_DEG = np.arange(-90.0, 91.0, 15.0)  # offsets the joint search starts from, around the current one
_ITERATIONS = 30
# How sure each bearing_reference makes us that there is no offset: the log-likelihood gain (nats) a learned
# offset must bring. True north from a DF is usually right; a magnetic reference often lacks its declination;
# an array's mount offset is often never measured.
PRIOR_LOG_ODDS = {"true_north": 20.0, "magnetic_north": 10.0, "vehicle": 5.0}


def shifted(pts: Points, offset: float) -> Points:
    """The points with `offset` (rad) taken off every bearing."""
    return Points(pts.east, pts.north, wrap_pi(pts.theta - offset), pts.sigma, pts.gps)


def joint_optimum(pts: Points, x0: np.ndarray, rob: Robust) -> tuple[float, np.ndarray, float]:
    """The best (offset, place, log posterior) of the points with an unknown constant offset: damped Gauss-Newton in
    (east, north, offset) with the mixture's EM weights, from starts every 15 deg (the offset's likelihood has a
    mode per way of lining the bearings up)."""
    best = (0.0, np.asarray(x0, float), -math.inf)
    for start in np.radians(_STARTS_DEG):
        b, x, lp = _gauss_newton(pts, np.asarray(x0, float), float(start), rob)
        if np.isfinite(lp) and lp > best[2] + 1e-9:
            best = (b, x, lp)
    return best


def _gauss_newton(pts: Points, x: np.ndarray, b: float, rob: Robust) -> tuple[float, np.ndarray, float]:
    """(offset, place, log posterior) after damped Gauss-Newton steps from (x, b) with the mixture's EM weights."""
    lp = float(log_posterior(x, shifted(pts, b), rob))
    for _ in range(_ITERATIONS):
        r, grad, w, _ = linearised(x, shifted(pts, b), rob)
        jac = np.column_stack([-grad, -np.ones_like(r)])  # of the residual theta - b - bearing(x)
        info = (jac * w[:, None]).T @ jac + 1e-9 * np.eye(3)
        try:
            delta = -np.linalg.solve(info, jac.T @ (w * r))
        except np.linalg.LinAlgError:
            break
        reach = math.hypot(x[0] - pts.east.mean(), x[1] - pts.north.mean()) + 100.0  # rays are nearly flat
        delta *= min(1.0, reach / max(float(np.hypot(delta[0], delta[1])), 1e-300))
        for step in (1.0, 0.5, 0.25):
            x_try, b_try = x + step * delta[:2], float(wrap_pi(b + step * delta[2]))
            lp_try = float(log_posterior(x_try, shifted(pts, b_try), rob))
            if np.isfinite(lp_try) and lp_try > lp:
                break
        else:
            break
        done = lp_try - lp < 1e-6
        x, b, lp = x_try, b_try, lp_try
        if done:
            break
    return b, x, lp


