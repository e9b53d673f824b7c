"""The particle-filter skeleton every algorithm plugs into: predict, log-domain weights, ESS, resampling,
estimate and covariance, plus the windowed posterior that move steps (MCMC, fish school) may target.

One `update(point)` is one observation point: predict -> weight -> `after_weight` hook -> resample when
`should_resample()` -> `after_resample` hook. A filter module overrides the hooks, nothing else.
"""
from __future__ import annotations

import math

import numpy as np

from ..config import LocalizerConfig
from ..types import ObservationPoint
from .likelihood import BearingLikelihood
from .resampling import SCHEMES


class PointHistory:
    """The last `size` observation points as arrays, for evaluating the posterior of a static emitter."""

    def __init__(self, size: int):
        self.size = size
        self.data = np.empty((0, 4))  # east, north, theta, sigma
        self.appended = 0  # points ever appended (the window may have dropped some)

    def append(self, p: ObservationPoint):
        row = np.array([[p.east, p.north, p.theta, p.sigma]])
        self.data = np.concatenate([self.data[-(self.size - 1):] if self.size > 1 else self.data[:0], row])
        self.appended += 1

    @property
    def dropped(self) -> int:
        return self.appended - len(self)

    def __len__(self):
        return self.data.shape[0]


class ParticleFilter:
    """Bootstrap skeleton; subclasses change behaviour only through the hooks."""

    name = "base"

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator):
        self.cfg = cfg
        self.rng = rng
        self.n = cfg.num_particles
        self.lik = BearingLikelihood(cfg.likelihood, cfg.outlier_prob, cfg.gps_sigma_m)
        self.resampler = SCHEMES[cfg.resampling]
        self.history = PointHistory(cfg.history_points)
        self.x = np.zeros((self.n, 2))
        self.logw = np.zeros(self.n)
        self.prior_mean = np.zeros(2)
        self.prior_prec = np.zeros((2, 2))  # precision of the Gaussian prior; zero = flat
        self.prev_logw = self.logw  # weights before the newest measurement (for hooks that re-weight)
        self.resampled = False  # whether the last update resampled
        self.skipped = 0  # updates refused because every particle had zero likelihood

    # -- set-up -------------------------------------------------------------------------------
    def initialise(self, particles: np.ndarray, prior_mean, prior_cov):
        """Start from given particles (equal weights) and a Gaussian prior the move steps respect."""
        self.x = np.array(particles, dtype=float).reshape(self.n, 2)
        self.initial = self.x.copy()  # the start cloud, kept for peers fed the same start (benchmark)
        self.logw = np.zeros(self.n)
        self.prior_mean = np.asarray(prior_mean, float)
        self.prior_prec = np.linalg.inv(np.asarray(prior_cov, float))

    # -- the skeleton ---------------------------------------------------------------------------
    def predict(self):
        """State model X_k = X_{k-1} + u, u ~ N(0, q^2 I) (paper eq. 17)."""
        q = self.cfg.process_noise_m
        if q > 0:
            self.x += q * self.rng.standard_normal(self.x.shape)

    def loglik(self, x: np.ndarray, p: ObservationPoint) -> np.ndarray:
        return self.lik.log(x, p.east, p.north, p.theta, p.sigma)

    def log_target(self, x: np.ndarray) -> np.ndarray:
        """Log posterior of a static emitter over the kept history (up to a constant), for move steps."""
        d = x - self.prior_mean
        lp = -0.5 * np.einsum("...i,ij,...j->...", d, self.prior_prec, d)
        h = self.history.data
        if len(h):
            lp = lp + self.lik.log(x[..., None, :], h[:, 0], h[:, 1], h[:, 2], h[:, 3]).sum(axis=-1)
        return lp

    @property
    def weights(self) -> np.ndarray:
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    def ess(self) -> float:
        """(sum w)^2 / sum w^2 of the unnormalised weights: 1/sum(w^2) without normalising first."""
        w = np.exp(self.logw - self.logw.max())
        return float(w.sum() ** 2 / np.dot(w, w))

    def should_resample(self) -> bool:
        return self.ess() < self.cfg.ess_threshold * self.n

    def resample(self) -> np.ndarray:
        """Resample in place; returns the ancestor indices."""
        idx = self.resampler(self.weights, self.rng)
        self.x = self.x[idx]
        self.logw = np.zeros(self.n)
        return idx

    def update(self, p: ObservationPoint) -> bool:
        """One measurement; False if it is unusable or no particle can explain it (weights untouched)."""
        if not (math.isfinite(p.theta) and p.sigma > 0 and math.isfinite(p.east) and math.isfinite(p.north)):
            self.skipped += 1
            self.resampled = False
            return False
        self.history.append(p)
        self.predict()
        self.prev_logw = self.logw
        self.last_ll = ll = self.loglik(self.x, p)
        new = self.logw + ll
        top = new.max()
        if not math.isfinite(top):
            self.skipped += 1
            self.resampled = False
            return False
        self.logw = new - top
        self.after_weight(p)
        self.resampled = self.should_resample()
        if self.resampled:
            self.resample()
            self.after_resample(p)
        return True

    # -- hooks ----------------------------------------------------------------------------------
    def after_weight(self, p: ObservationPoint):
        """Called after weighting with the new measurement (the fish school runs here in the paper)."""

    def after_resample(self, p: ObservationPoint):
        """Called after resampling (move steps that restore diversity run here)."""

    # -- output ---------------------------------------------------------------------------------
    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean (eq. 25) and weighted covariance of the cloud."""
        w = self.weights
        mean = w @ self.x
        d = self.x - mean
        cov = (w[:, None] * d).T @ d
        return mean, cov
