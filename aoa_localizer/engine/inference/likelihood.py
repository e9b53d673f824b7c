"""Bearing likelihoods, in log form and vectorised over particles and observation points."""
from __future__ import annotations

import math

import numpy as np

from aoa_localizer.engine.geodesy import TWO_PI

_LOG_SQRT_2PI = 0.5 * math.log(TWO_PI)
_BELOW_FLOOR = 40.0  # exp(-40) = 4e-18 < 2^-53: below this under log(c), exp(g) + c == c


def gaussian_loglik_var(residual, var):
    """log N(residual; 0, var), from the variance: no square root where the variance varies per particle."""
    if np.ndim(var) == 0:
        return (-0.5 / var) * np.square(residual) - (0.5 * math.log(var) + _LOG_SQRT_2PI)
    g = np.square(residual)
    g /= var
    g += np.log(var)
    g *= -0.5
    g -= _LOG_SQRT_2PI
    return g


def mixture_loglik(residual, sigma, outlier_prob: float):
    """log((1 - e) N(residual; 0, sigma^2) + e / 2pi): a wild bearing costs at most log(e / 2pi)."""
    return mixture_loglik_var(residual, np.square(sigma), outlier_prob)


def mixture_loglik_var(residual, var, outlier_prob: float):
    """mixture_loglik from the variance. Written as log(exp(g) + c): where exp(g) underflows the result is log(c),
    exactly the floor. g is first raised to log(c) - 40, where exp(g) is already below half an ulp of c (the same
    result to the last bit): exp's slow path for arguments that underflow took 90 % of this function's time. The
    steps are made in place on one array (a fresh temporary per step cost more than its arithmetic)."""
    g = np.asarray(gaussian_loglik_var(residual, var), dtype=float)
    if g.ndim == 0:
        g = g.reshape(1)
        return _mixture_in_place(g, outlier_prob)[0]
    return _mixture_in_place(g, outlier_prob)


def _mixture_in_place(g: np.ndarray, outlier_prob: float) -> np.ndarray:
    g += math.log1p(-outlier_prob)
    return g if outlier_prob == 0 else _add_outlier_floor(g, outlier_prob)


def _add_outlier_floor(g: np.ndarray, outlier_prob: float) -> np.ndarray:
    """log(exp(g) + e / 2pi) in place, for g already holding log((1 - e) N)."""
    c = outlier_prob / TWO_PI
    np.maximum(g, math.log(c) - _BELOW_FLOOR, out=g)
    np.exp(g, out=g)
    g += c
    return np.log(g, out=g)


class BearingLikelihood:
    """L(z | x) for a bearing z taken at (east, north) with standard deviation sigma.

    An antenna position known to `gps_sigma_m` (configured, for every point) or to each point's own `gps_sigma`
    (from its fixes' covariances) adds (sigma / range)^2 to the bearing variance.
    """

    def __init__(self, kind: str, outlier_prob: float, gps_sigma_m: float = 0.0):
        self.outlier_prob = outlier_prob if kind == "mixture" else 0.0
        self.gps_var = gps_sigma_m**2

    def log(self, particles: np.ndarray, east, north, theta, sigma, gps_sigma=0.0) -> np.ndarray:
        """Log-likelihood; broadcasting (N, 1, 2) particles against (K,) points gives (N, K).

        The residual z - bearing(x) is the angle from the antenna->particle direction d to the
        measured direction u: atan2(d x u, d . u), already in (-pi, pi] without wrapping.
        """
        if isinstance(theta, float) and isinstance(sigma, float) and isinstance(gps_sigma, (float, int)):
            return self._one_point(particles, east, north, theta, sigma, gps_sigma)
        dx, dy = particles[..., 0] - east, particles[..., 1] - north
        if np.ndim(theta) == 0:
            c, s = math.cos(theta), math.sin(theta)
        else:
            c, s = np.cos(theta), np.sin(theta)
        r = np.arctan2(dx * s - dy * c, dx * c + dy * s)
        var = np.square(sigma)
        gps_var = self.gps_var + np.square(gps_sigma)
        if np.any(gps_var):
            with np.errstate(over="ignore"):  # a particle run off to 1e200 m: its GPS term is simply 0
                d2 = np.square(dx)
                d2 += np.square(dy)
                np.maximum(d2, 1.0, out=d2)
                np.divide(gps_var, d2, out=d2)
                d2 += var
                var = d2
        return mixture_loglik_var(r, var, self.outlier_prob)

    def _one_point(self, particles: np.ndarray, east, north, theta: float, sigma: float, gps_sigma) -> np.ndarray:
        """log() for one point (a filter step's case): its numbers in plain floats and the fewest array steps,
        in place on one array; log()'s general code is the reference the tests hold this to. The antenna's
        position term is (gps sigma / range)^2 from the range by hypot, which cannot overflow."""
        dx, dy = particles[..., 0] - east, particles[..., 1] - north
        c, s = math.cos(theta), math.sin(theta)
        r = np.arctan2(dx * s - dy * c, dx * c + dy * s)
        gps_var = self.gps_var + gps_sigma * gps_sigma
        eps = self.outlier_prob
        shift = _LOG_SQRT_2PI - math.log1p(-eps)  # the mixture's (1 - e) folded into the constant
        g = np.square(r, out=r)
        if gps_var > 0:
            var = np.hypot(dx, dy, out=dx)
            np.maximum(var, 1.0, out=var)
            np.divide(math.sqrt(gps_var), var, out=var)
            np.square(var, out=var)
            var += sigma * sigma
            g /= var
            g += np.log(var, out=var)
            g *= -0.5
            g -= shift
        else:
            var0 = sigma * sigma
            g *= -0.5 / var0
            g -= 0.5 * math.log(var0) + shift
        return g if eps == 0 else _add_outlier_floor(g, eps)
