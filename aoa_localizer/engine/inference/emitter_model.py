"""The emitter problem: a static 2-D emitter seen through bearings from known antenna positions."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.global_search import (
    Points,
    Robust,
    hypotheses_log_joint,
    latent_log_densities,
    log_posterior,
    log_posterior_given,
    reach_log_prior,
)
from aoa_localizer.engine.inference.likelihood import BearingLikelihood
from aoa_localizer.engine.inference.receiver import NoiseGrid, log_sum
from aoa_localizer.engine.scheduling.slices import LOOKS, metered
from aoa_localizer.engine.types import ObservationPoint
from aoa_localizer.models.base import StateSpaceModel


class PointHistory:
    """The last `size` observation points as arrays, for evaluating the posterior of a static emitter."""

    def __init__(self, size: int):
        self.size = size
        self.data = np.empty((0, 5))  # east, north, theta, sigma, gps_sigma
        self.appended = 0  # points ever appended (the window may have dropped some)

    def append(self, p: ObservationPoint):
        row = np.array([[p.east, p.north, p.theta, p.sigma, p.gps_sigma]])
        self.data = np.concatenate([self.data[-(self.size - 1):] if self.size > 1 else self.data[:0], row])
        self.appended += 1

    @property
    def dropped(self) -> int:
        return self.appended - len(self)

    def __len__(self):
        return self.data.shape[0]


@dataclass
class RunningSums:
    """Per particle and noise hypothesis, the log densities of the points `rows` at the particles `x` (N, H)
    (receiver.log_densities): the next point's weight adds that point's alone when the cloud and the points
    are still these."""

    x: np.ndarray
    rows: np.ndarray
    grid: NoiseGrid
    gps_var: float
    sums: np.ndarray

    def covers(self, x: np.ndarray, rows: np.ndarray, grid: NoiseGrid, gps_var: float) -> bool:
        return (grid is self.grid and gps_var == self.gps_var and x.shape == self.x.shape
                and rows.shape == self.rows.shape and np.array_equal(x, self.x) and np.array_equal(rows, self.rows))


class EmitterModel(StateSpaceModel):
    """X_k = X_{k-1} + N(0, q^2 I) (paper eq. 17); z = bearing from the point's antenna (eq. 18)."""

    dim = 2

    def __init__(self, cfg: LocalizerConfig, grid: NoiseGrid | None = None,
                 reach: tuple[float, float, float] | None = None, outlier_prob: float | None = None):
        """`grid`, `reach`: as below; `outlier_prob`: the point outlier share the receiver's calibration learned (None:
        the configured one)."""
        self.q = cfg.process_noise_m
        self.lik = BearingLikelihood(cfg.likelihood, cfg.outlier_prob, cfg.gps_sigma_m)
        if outlier_prob is not None:
            self.lik.outlier_prob = outlier_prob
        self.history = PointHistory(cfg.history_points)
        self.prior_mean = np.zeros(2)
        self.prior_prec = np.zeros((2, 2))  # precision of the Gaussian prior; zero = flat
        # The receiver's noise while it is not known: marginalised over these hypotheses (None: the points' sigmas
        # and the likelihood's outlier share are taken as they are)
        self.grid = grid
        self.reach = reach  # global_search.Robust.reach
        self.sums: RunningSums | None = None  # the last point weight's, under the latent noise

    def set_prior(self, mean, cov):
        self.prior_mean = np.asarray(mean, float)
        self.prior_prec = np.linalg.inv(np.asarray(cov, float))

    def transition(self, x, k, rng):
        return x + self.q * rng.standard_normal(x.shape) if self.q > 0 else x

    def transition_logpdf(self, x, x_prev, k):
        d = x - x_prev
        q2 = max(self.q, 1e-9) ** 2
        return -0.5 * np.sum(d * d, axis=-1) / q2 - math.log(2 * math.pi * q2)

    def ukf(self, k, p: ObservationPoint):
        """(f, Q, h, R, angles, z): random walk, the bearing from the point's antenna (an angle)."""
        h = lambda X: np.arctan2(X[..., 1] - p.north, X[..., 0] - p.east)[..., None]  # noqa: E731
        return (lambda X: X, max(self.q, 1e-3) ** 2 * np.eye(2), h, np.array([[p.sigma**2]]), [True],
                np.array([p.theta]))

    def loglik(self, x, p: ObservationPoint, k=None):
        if self.grid is not None and len(self.history) and self.history.data[-1, 2] == p.theta:
            # The noise is shared by all points: the newest point's weight is the predictive ratio of the posteriors
            # with and without it (every filter weights a point after observing it).
            return self._point_weight(np.asarray(x, float))
        return self.lik.log(x, p.east, p.north, p.theta, p.sigma, p.gps_sigma)

    def _point_weight(self, x: np.ndarray) -> np.ndarray:
        """The newest point's weight under the latent noise, log sum_h prior_h exp(S_h + d_h) - log sum_h prior_h
        exp(S_h), with S the log densities of the points before it and d its own (the posterior's prior on x
        cancels): S is the last weight's running sum when that covered exactly these points at these particles
        (no move or re-start in between), so a point costs O(N H) instead of two passes over all K points."""
        assert self.grid is not None
        h, gps_var = self.history.data, self.lik.gps_var
        rob = Robust(0.0, math.sqrt(gps_var), grid=self.grid)
        s = self.sums
        if s is not None and s.covers(x, h[:-1], self.grid, gps_var):
            before = s.sums
        else:
            before = latent_log_densities(x, Points.of(h[:-1]), rob)
        after = before + latent_log_densities(x, Points.of(h[-1:]), rob)
        self.sums = RunningSums(x.copy(), h.copy(), self.grid, gps_var, after)
        return log_sum(after, self.grid) - log_sum(before, self.grid)

    def _latent_posterior(self, x, h: np.ndarray) -> np.ndarray:
        """The log posterior over the points h with the noise marginalised over the grid: the global search's."""
        return log_posterior(np.asarray(x, float), Points.of(h), self._latent())

    def _latent(self) -> Robust:
        return Robust(0.0, math.sqrt(self.lik.gps_var), self.prior_mean, self.prior_prec, self.grid, self.reach)

    def hypotheses_log_joint(self, x: np.ndarray) -> np.ndarray | None:
        """log p(x, h | kept points) per noise hypothesis h, (N, H); None while the noise is taken as known."""
        if self.grid is None:
            return None
        return hypotheses_log_joint(np.asarray(x, float), Points.of(self.history.data), self._latent())

    @metered(LOOKS, lambda self, x, h: 0)
    def log_posterior_given(self, x: np.ndarray, h: np.ndarray) -> np.ndarray:
        """log p(x, h | kept points) at each row of x (M, 2) with its own hypothesis h (M,): hypotheses_log_joint's
        column, made at the cost of one hypothesis (its kernels metered, and the move's own work as a look's)."""
        return log_posterior_given(np.asarray(x, float), Points.of(self.history.data), self._latent(), h)

    def usable(self, p: ObservationPoint) -> bool:
        return math.isfinite(p.theta) and p.sigma > 0 and math.isfinite(p.east) and math.isfinite(p.north)

    def observe(self, p: ObservationPoint):
        self.history.append(p)

    def log_posterior(self, x: np.ndarray) -> np.ndarray:
        """Log posterior of a static emitter over the kept history (up to a constant), for move steps."""
        h = self.history.data
        if self.grid is not None:
            return self._latent_posterior(x, h)
        d = x - self.prior_mean
        lp = -0.5 * np.einsum("...i,ij,...j->...", d, self.prior_prec, d)
        if self.reach is not None:
            lp = lp + reach_log_prior(x, self.reach)
        if len(h):
            lp = lp + self._log_likelihood(x, h)
        return lp

    @metered(LOOKS, lambda self, x, h: np.size(x) // 2 * len(h))
    def _log_likelihood(self, x: np.ndarray, h: np.ndarray) -> np.ndarray:
        """The kept points' log likelihood at each place of x (..., 2), the noise taken as it is."""
        return self.lik.log(x[..., None, :], h[:, 0], h[:, 1], h[:, 2], h[:, 3], h[:, 4]).sum(axis=-1)
