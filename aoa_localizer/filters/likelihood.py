"""Bearing likelihoods, in log form and vectorised over particles and observation points."""
from __future__ import annotations

import math

import numpy as np

from ..geodesy import TWO_PI, wrap_pi

_LOG_SQRT_2PI = 0.5 * math.log(TWO_PI)


def gaussian_loglik(residual, sigma):
    """log N(residual; 0, sigma^2): the paper's likelihood (eq. 24) with its normalising constant."""
    return -0.5 * (residual / sigma) ** 2 - np.log(sigma) - _LOG_SQRT_2PI


def mixture_loglik(residual, sigma, outlier_prob: float):
    """log((1 - e) N(residual; 0, sigma^2) + e / 2pi): a wild bearing costs at most log(e / 2pi)."""
    g = gaussian_loglik(residual, sigma) + math.log1p(-outlier_prob)
    if outlier_prob == 0:
        return g
    return np.logaddexp(g, math.log(outlier_prob / TWO_PI))


class BearingLikelihood:
    """L(z | x) for a bearing z taken at (east, north) with standard deviation sigma.

    An antenna position known to `gps_sigma_m` adds (gps_sigma_m / range)^2 to the bearing variance.
    """

    def __init__(self, kind: str, outlier_prob: float, gps_sigma_m: float = 0.0):
        self.kind = kind
        self.outlier_prob = outlier_prob if kind == "mixture" else 0.0
        self.gps_var = gps_sigma_m**2

    def log(self, particles: np.ndarray, east, north, theta, sigma) -> np.ndarray:
        """Log-likelihood; broadcasting (N, 1, 2) particles against (K,) points gives (N, K)."""
        dx, dy = particles[..., 0] - east, particles[..., 1] - north
        r = wrap_pi(theta - np.arctan2(dy, dx))
        if self.gps_var:
            sigma = np.sqrt(sigma**2 + self.gps_var / np.maximum(dx * dx + dy * dy, 1.0))
        return mixture_loglik(r, sigma, self.outlier_prob)
