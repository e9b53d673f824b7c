"""Triangulation start of the AFSA paper (sec. 3.3, eqs. 22-23): initial particles from crossing bearing rays.

Records are sorted by bearing and paired a fixed interval apart (neighbours are nearly parallel).
Pairs that cross at less than `init_min_crossing_deg`, or whose rays meet behind either antenna,
are refused, and so are pairs whose crossing point is not supported by at least `min_support` of
all the records (bearing within 3 sigma of it): one wild bearing crossing the others steeply would
otherwise seed the whole cloud far from the emitter. Each particle is the crossing of one good pair with
both bearings redrawn from their noise, so the cloud has the spread the two bearings really allow.
"""

from __future__ import annotations

import math

import numpy as np

from aoa_localizer.engine.geodesy import circular_mean, wrap_pi
from aoa_localizer.engine.types import ObservationPoint

# Redraws per particle before the cloud is filled by repeating the good draws.
_DRAW_FACTOR = 4
# A record supports a crossing point when its bearing points at it within this many sigmas.
_SUPPORT_SIGMAS = 3.0


def intersect_rays(p1, t1, p2, t2):
    """Crossing of rays p1 + s1 u(t1) and p2 + s2 u(t2), the same point as eqs. 22-23 without tangents.

    Returns (points (..., 2), s1, s2): s1, s2 are the distances along each ray (negative: behind the
    antenna); parallel rays give NaN.
    """
    p1, p2 = np.asarray(p1, float), np.asarray(p2, float)
    u1 = np.stack([np.cos(t1), np.sin(t1)], axis=-1)
    u2 = np.stack([np.cos(t2), np.sin(t2)], axis=-1)
    d = p2 - p1
    cross = u1[..., 0] * u2[..., 1] - u1[..., 1] * u2[..., 0]  # sin(t2 - t1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s1 = (d[..., 0] * u2[..., 1] - d[..., 1] * u2[..., 0]) / cross
        s2 = (d[..., 0] * u1[..., 1] - d[..., 1] * u1[..., 0]) / cross
    s1 = np.where(cross == 0, np.nan, s1)
    s2 = np.where(cross == 0, np.nan, s2)
    return p1 + s1[..., None] * u1, s1, s2


def least_squares_crossing(xy: np.ndarray, theta: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray | None:
    """The place nearest the lines from `xy` (K, 2) at ENU angles `theta` (K,): least squares of the perpendicular
    distances, each weighted by `weights` (None: equally); None when the lines are parallel."""
    normal = np.column_stack([-np.sin(theta), np.cos(theta)])
    w = np.ones(len(xy)) if weights is None else np.asarray(weights, float)
    a = (normal * w[:, None]).T @ normal
    if abs(np.linalg.det(a)) <= 1e-12 * float(np.trace(a)) ** 2:  # parallel, whatever the weights' scale
        return None
    return np.linalg.solve(a, (normal * w[:, None]).T @ np.einsum("ki,ki->k", normal, xy))


def sorted_pairs(points: list[ObservationPoint]) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j): records sorted by bearing (around their circular mean), half the count apart."""
    theta = np.array([p.theta for p in points])
    order = np.argsort(wrap_pi(theta - circular_mean(theta)), kind="stable")
    h = max(1, len(points) // 2)
    return order[:-h], order[h:]


def support(candidates: np.ndarray, pos: np.ndarray, theta: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Share of records whose bearing points at each candidate (C, 2) within _SUPPORT_SIGMAS sigmas."""
    seen = np.arctan2(candidates[:, None, 1] - pos[None, :, 1], candidates[:, None, 0] - pos[None, :, 0])
    return np.mean(np.abs(wrap_pi(theta[None, :] - seen)) <= _SUPPORT_SIGMAS * sigma[None, :], axis=1)


def good_pairs(
    points: list[ObservationPoint], min_crossing_deg: float, min_support: float
) -> tuple[np.ndarray, np.ndarray, str]:
    """The sorted pairs whose rays cross steeply, in front of both antennas, at a point most records support."""
    if len(points) < 2:
        return np.array([], int), np.array([], int), "fewer than two observation points"
    i, j = sorted_pairs(points)
    pos = np.array([[p.east, p.north] for p in points])
    theta = np.array([p.theta for p in points])
    sigma = np.array([p.sigma for p in points])
    xy, s1, s2 = intersect_rays(pos[i], theta[i], pos[j], theta[j])
    crossing = np.abs(np.sin(theta[j] - theta[i]))
    steep = crossing >= math.sin(math.radians(min_crossing_deg))
    ahead = (s1 > 0) & (s2 > 0)
    shares = np.zeros(i.size)
    if (steep & ahead).any():
        shares[steep & ahead] = support(xy[steep & ahead], pos, theta, sigma)
    ok = steep & ahead & (shares >= min_support)
    if ok.any():
        return i[ok], j[ok], ""
    if not steep.any():
        best = math.degrees(math.asin(min(1.0, float(crossing.max())))) if crossing.size else 0.0
        why = f"bearings nearly parallel: best crossing {best:.1f} deg < {min_crossing_deg:g} deg"
    elif not (steep & ahead).any():
        why = "the steep pairs cross behind the antenna"
    else:
        why = f"no steep crossing is supported by enough bearings (best {shares.max():.0%} < {min_support:.0%})"
    return i[ok], j[ok], why


def initial_particles(
    points: list[ObservationPoint], n: int, min_crossing_deg: float, min_support: float, rng: np.random.Generator
) -> tuple[np.ndarray | None, str]:
    """N initial particles from crossing pairs with redrawn bearing noise, or (None, reason) if the geometry is poor."""
    i, j, why = good_pairs(points, min_crossing_deg, min_support)
    if i.size == 0:
        return None, why
    pos = np.array([[p.east, p.north] for p in points])
    theta = np.array([p.theta for p in points])
    sigma = np.array([p.sigma for p in points])
    pick = rng.integers(0, i.size, size=_DRAW_FACTOR * n)
    a, b = i[pick], j[pick]
    ta = theta[a] + sigma[a] * rng.standard_normal(a.size)
    tb = theta[b] + sigma[b] * rng.standard_normal(b.size)
    xy, s1, s2 = intersect_rays(pos[a], ta, pos[b], tb)
    valid = (s1 > 0) & (s2 > 0) & (np.abs(np.sin(tb - ta)) >= math.sin(math.radians(min_crossing_deg) / 2))
    xy = xy[valid]
    if xy.shape[0] == 0:
        return None, "no redrawn pair crosses in front of the antennas"
    if xy.shape[0] < n:
        xy = xy[rng.integers(0, xy.shape[0], size=n)]
    return xy[:n].copy(), ""
