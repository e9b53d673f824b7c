"""A constant bearing offset, learned where the data determine it: a mount offset left at 0, a forgotten magnetic
declination, a DF whose north is off. Every bearing then reads the same angle off; on a drive with turns no single
place explains them all, and the joint optimum of (place, offset) stands out from the place alone.

Where the data cannot tell an offset from a place (a straight drive, a few bearings from one side), the reference's
residual misalignment stays unknown, and the published estimate is marginalised over it (`marginalise`).

Offsets are ENU radians: the corrected bearing is the given one minus the offset, so a true azimuth is the read
azimuth plus the offset in degrees (ENU angles run the other way round).
"""
from __future__ import annotations

import math

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.inference.global_search import Points, Robust, linearised, log_posterior
from aoa_localizer.engine.scheduling.slices import RESIDUALS, metered

_STARTS_DEG = np.arange(-90.0, 91.0, 15.0)  # offsets the joint search starts from, around the current one
ALL_OFFSETS_DEG = np.arange(-180.0, 180.0, 15.0)  # the starts where any offset is as likely (an array's mount)
_ITERATIONS = 30
# How sure each bearing_reference makes us that there is no offset: the log-likelihood gain (nats) a learned
# offset must bring. True north from a DF is usually right; a magnetic reference often lacks its declination;
# an array's mount offset is often never measured.
PRIOR_LOG_ODDS = {"true_north": 20.0, "magnetic_north": 10.0, "vehicle": 5.0}
# How far a configured reference's zero may still be off (deg, one standard deviation) when `offset_sigma_deg`
# is left to the reference: a DF that says true north is taken at its word (a gross error is the learned
# offset's job); a compass carries the vehicle's own magnetism and the declination model's error; an array's
# forward axis is a few degrees off once measured (`mount_offset_deg` set), and anything when it never was.
RESIDUAL_SD_DEG = {"true_north": 0.0, "magnetic_north": 2.0, "vehicle": 10.0}
MEASURED_MOUNT_SD_DEG = 3.0


def prior_sd(cfg: LocalizerConfig) -> float:
    """The residual offset's prior standard deviation (rad): `offset_sigma_deg`, or by the bearing reference."""
    if cfg.offset_sigma_deg >= 0.0:
        return math.radians(cfg.offset_sigma_deg)
    if cfg.bearing_reference == "vehicle" and cfg.mount_offset_deg != 0.0:
        return math.radians(MEASURED_MOUNT_SD_DEG)
    return math.radians(RESIDUAL_SD_DEG[cfg.bearing_reference])


def marginalise(pts: Points, x: np.ndarray, rob: Robust, sd: float) -> tuple[np.ndarray, np.ndarray]:
    """The shift (2,) and added covariance (2, 2) that take a place x estimated at the offset in use to the
    posterior marginalised over a residual offset of prior N(0, sd^2) (rad; inf: flat, an offset already learned),
    to first order: the points' Fisher information in (place, offset) says how far the place moves per radian of
    offset (g = I_xx^-1 I_xb) and what the points leave of the offset's variance, 1 / (I_bb - I_bx g + 1 / sd^2);
    the offset's mean is one Gauss-Newton step from the residuals. (0, 0) when sd is 0 or the points are
    degenerate."""
    none = (np.zeros(2), np.zeros((2, 2)))
    if sd <= 0.0 or pts.east.size < 2:
        return none
    resid, grad, w, _ = linearised(np.asarray(x, float), pts, rob)
    i_xx = (grad * w[:, None]).T @ grad
    i_xb = grad.T @ w
    try:
        g = np.linalg.solve(i_xx, i_xb)
    except np.linalg.LinAlgError:
        return none
    info = float(w.sum() - i_xb @ g) + 1.0 / sd**2
    if not (np.all(np.isfinite(g)) and info > 0.0):
        return none
    wr = w * resid
    mean = float(wr.sum() - g @ (grad.T @ wr)) / info
    if not math.isfinite(mean):
        return none
    return -g * mean, np.outer(g, g) / info


# the bearings wrapped, their cosines and sines: a residual's work per element
@metered(RESIDUALS, lambda pts, offset: math.prod(np.broadcast_shapes(np.shape(pts.theta), np.shape(offset))))
def shifted(pts: Points, offset: float | np.ndarray) -> Points:
    """The points with `offset` (rad) taken off every bearing; offsets (M, 1) give each of M rows its own."""
    theta = wrap_pi(pts.theta - offset)
    return Points(pts.east, pts.north, theta, pts.sigma, pts.gps)


def joint_optimum(pts: Points, x0: np.ndarray, rob: Robust,
                  starts_deg: np.ndarray | None = None) -> tuple[float, np.ndarray, float]:
    """The best (offset, place, log posterior) of the points with an unknown constant offset: damped Gauss-Newton in
    (east, north, offset) with the mixture's EM weights, from starts every 15 deg (the offset's likelihood has a
    mode per way of lining the bearings up): within 90 deg of the current one unless `starts_deg` says. Every start
    at once, each on its own path (a test holds them to one start at a time)."""
    b = np.radians(_STARTS_DEG if starts_deg is None else starts_deg).astype(float)
    x = np.repeat(np.asarray(x0, float)[None, :], b.size, axis=0)
    lp = log_posterior(x, shifted(pts, b[:, None]), rob)
    active = np.arange(b.size)  # the starts still moving
    for _ in range(_ITERATIONS):
        if not active.size:
            break
        moved, done = _step(pts, rob, x, b, lp, active)
        active = active[moved & ~done]
    best = (0.0, np.asarray(x0, float), -math.inf)
    for i in range(b.size):  # the first of equals, in the starts' order
        if np.isfinite(lp[i]) and lp[i] > best[2] + 1e-9:
            best = (float(b[i]), x[i].copy(), float(lp[i]))
    return best


def _step(pts: Points, rob: Robust, x: np.ndarray, b: np.ndarray, lp: np.ndarray, active: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """One damped Gauss-Newton step of the `active` starts, x, b and lp updated in place: the first of the step
    lengths 1, 1/2, 1/4 that raises the log posterior. (moved, converged: it rose by under 1e-6) per active start;
    a start that did not move is at its optimum."""
    xa, ba, lpa = x[active], b[active], lp[active]
    r, grad, w, _ = linearised(xa, shifted(pts, ba[:, None]), rob)
    jac = np.concatenate([-grad, -np.ones(r.shape + (1,))], axis=-1)  # of the residual theta - b - bearing(x)
    info = np.einsum("ak,aki,akj->aij", w, jac, jac) + 1e-9 * np.eye(3)
    rhs = np.einsum("aki,ak->ai", jac, w * r)
    solvable = np.isfinite(info).all(axis=(1, 2)) & (np.abs(np.linalg.det(info)) > 0.0)
    delta = np.zeros((active.size, 3))
    if solvable.any():
        delta[solvable] = -np.linalg.solve(info[solvable], rhs[solvable][..., None])[..., 0]
    reach = np.hypot(xa[:, 0] - pts.east.mean(), xa[:, 1] - pts.north.mean()) + 100.0  # rays are nearly flat
    delta *= np.minimum(1.0, reach / np.maximum(np.hypot(delta[:, 0], delta[:, 1]), 1e-300))[:, None]
    moved = np.zeros(active.size, bool)
    new_lp = lpa.copy()
    for step in (1.0, 0.5, 0.25):
        todo = np.flatnonzero(solvable & ~moved)
        if not todo.size:
            break
        x_try, b_try = xa[todo] + step * delta[todo, :2], wrap_pi(ba[todo] + step * delta[todo, 2])
        lp_try = log_posterior(x_try, shifted(pts, b_try[:, None]), rob)
        up = np.isfinite(lp_try) & (lp_try > lpa[todo])
        took = todo[up]
        x[active[took]], b[active[took]], new_lp[took] = x_try[up], b_try[up], lp_try[up]
        moved[took] = True
    lp[active] = new_lp
    return moved, new_lp - lpa < 1e-6

