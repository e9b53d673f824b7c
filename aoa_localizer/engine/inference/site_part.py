"""A steady site part that neighbouring points share, and what it adds to the filter's estimate (docs/design.md,
"A site part along the road").

A point's bearing error is its readings' noise plus a site part that the points near it share (multipath off the
same buildings, a stretch of road's steady bias): Gaussian, sd tau, correlated over the antennas' distance as a
Gaussian of scale `stretch`. The filter takes the points as independent; where tau is not zero its posterior is too
narrow by the number of points that share each site error. Here tau is learned from the filter's points at its
estimate by restricted maximum likelihood (the estimate's two coordinates taken out, so the part of the site error
the place absorbed is not lost), averaged over its posterior on a grid (tau = 0 holds half the prior: the part may be
absent), and the estimate gets the covariance the site part adds (a sandwich with the points' information).
"""
from __future__ import annotations

import math

import numpy as np

from aoa_localizer.engine.inference.global_search import Points, Robust, linearised

MIN_POINTS = 12  # fewer inlying points cannot show a site part
FIT_POINTS = 200  # the fit reads at most this many points (every k-th): its cost is cubic in them
STRETCHES_M = (100.0, 300.0, 1000.0)  # the site part's correlation scales tried
_TAUS = np.radians(np.concatenate([[0.0], np.geomspace(0.1, 20.0, 24)]))  # its sd, rad
_ZERO_PRIOR = 0.5  # the prior's mass on no site part
_SCALES = np.geomspace(0.3, 5.0, 20)  # the points' own noise, a factor on their sigmas (learned beside tau)


def site_part_spread(pts: Points, x: np.ndarray, rob: Robust) -> np.ndarray:
    """The covariance (2, 2) the points' site part adds to an estimate at x: sum over the stretches of the
    posterior mean of tau^2 times A^-1 G' K G A^-1 (A the inlying points' information, G their weighted
    gradients, K the part's correlation between them); zero with fewer than MIN_POINTS inlying points."""
    none = np.zeros((2, 2))
    resid, grad, w, gamma = linearised(np.asarray(x, float), pts, rob)
    keep = gamma > 0.5
    if keep.sum() < MIN_POINTS:
        return none
    east, north, r, jac, sigma = pts.east[keep], pts.north[keep], resid[keep], grad[keep], pts.sigma[keep]
    g = jac * w[keep][:, None]
    try:
        inv = np.linalg.inv(g.T @ jac)
    except np.linalg.LinAlgError:
        return none
    if not np.all(np.isfinite(inv)):
        return none
    step = max(1, math.ceil(keep.sum() / FIT_POINTS))
    tau2 = mean_tau2(east[::step], north[::step], r[::step], jac[::step], sigma[::step])
    d2 = np.square(east[:, None] - east[None, :]) + np.square(north[:, None] - north[None, :])
    added = np.zeros((2, 2))
    for stretch, t2 in tau2.items():
        if t2 > 0.0:
            added += t2 * inv @ (g.T @ np.exp(-0.5 * d2 / stretch**2) @ g) @ inv
    return 0.5 * (added + added.T)


def mean_tau2(east: np.ndarray, north: np.ndarray, resid: np.ndarray, jac: np.ndarray, sigma: np.ndarray
              ) -> dict[float, float]:
    """Each stretch's share of the posterior mean of tau^2 (rad^2) given the points' residuals (rad) and gradients at
    the estimate: the restricted likelihood over a grid of tau, the noise's scale and the stretch (equal prior
    weight each stretch; tau = 0 _ZERO_PRIOR of it, the rest even in log tau; the scale even in log). Zero where the
    posterior holds half or more of its mass at tau = 0: precise bearings that show no site part keep their ellipse
    (a site part the data cannot rule out would otherwise widen it, two cars' fused ellipse 1.9x)."""
    rw, xw = resid / sigma, jac / sigma[:, None]  # whitened by the points' own sigmas
    d2 = np.square(east[:, None] - east[None, :]) + np.square(north[:, None] - north[None, :])
    c2 = np.square(_SCALES)[:, None, None]
    t2 = np.square(_TAUS)[None, :, None]
    log_prior = np.log(np.where(_TAUS == 0.0, _ZERO_PRIOR, (1.0 - _ZERO_PRIOR) / (_TAUS.size - 1)))[None, :]
    lls = []
    for stretch in STRETCHES_M:
        lam, u = np.linalg.eigh(np.exp(-0.5 * d2 / stretch**2) / np.outer(sigma, sigma))
        rt, xt = u.T @ rw, u.T @ xw
        inv_d = 1.0 / (c2 + t2 * np.maximum(lam, 0.0)[None, None, :])  # (scales, taus, points)
        m00, m01, m11 = (inv_d @ (xt[:, 0] ** 2), inv_d @ (xt[:, 0] * xt[:, 1]), inv_d @ (xt[:, 1] ** 2))
        b0, b1 = inv_d @ (xt[:, 0] * rt), inv_d @ (xt[:, 1] * rt)
        det = np.maximum(m00 * m11 - m01**2, 1e-300)
        explained = (m11 * b0**2 - 2.0 * m01 * b0 * b1 + m00 * b1**2) / det
        ll = -0.5 * (-np.log(inv_d).sum(axis=-1) + np.log(det) + inv_d @ rt**2 - explained) + log_prior
        lls.append(ll)
    stacked = np.stack(lls)  # (stretches, scales, taus)
    post = np.exp(stacked - stacked.max())
    post /= post.sum()
    if post[:, :, _TAUS == 0.0].sum() >= 0.5:  # the data favour no site part: the filter's own ellipse stands
        return {stretch: 0.0 for stretch in STRETCHES_M}
    return {stretch: float((post[k] * np.square(_TAUS)[None, :]).sum()) for k, stretch in enumerate(STRETCHES_M)}
