"""The particle-filter skeleton every algorithm plugs into: predict, log-domain weights, ESS, resampling,
estimate and covariance, over any StateSpaceModel (the emitter problem, or a paper's benchmark model).

One `update(z)` is one measurement: propose (by default: predict with the model's transition) -> weight
-> `after_weight` hook -> resample when `should_resample()` -> `after_resample` hook. A filter module
overrides the hooks, nothing else.
"""
from __future__ import annotations

import numpy as np

from ..config import LocalizerConfig
from ..models import EmitterModel, StateSpaceModel
from .resampling import SCHEMES


class ParticleFilter:
    """Bootstrap skeleton; subclasses change behaviour only through the hooks."""

    name = "base"

    def __init__(self, cfg: LocalizerConfig, rng: np.random.Generator, model: StateSpaceModel | None = None):
        self.cfg = cfg
        self.rng = rng
        self.model = model if model is not None else EmitterModel(cfg)
        self.n = cfg.num_particles
        self.resampler = SCHEMES[cfg.resampling]
        self.x = np.zeros((self.n, self.model.dim))
        self.logw = np.zeros(self.n)
        self.k = 0  # measurements taken
        self.x_prev = self.x  # particles before the newest prediction (ESPF's parents)
        self.prev_logw = self.logw  # weights before the newest measurement (for hooks that re-weight)
        self.last_ll = np.zeros(self.n)  # log-likelihood of the newest measurement at the predicted particles
        self.last_idx = np.arange(self.n)  # ancestors chosen by the last resampling
        self.resampled = False  # whether the last update resampled
        self.skipped = 0  # updates refused: unusable measurement, or no particle could explain it

    # -- set-up -------------------------------------------------------------------------------
    def initialise(self, particles: np.ndarray, prior_mean=None, prior_cov=None):
        """Start from given particles (equal weights); the emitter model also takes a Gaussian prior."""
        self.x = np.array(particles, dtype=float).reshape(self.n, self.model.dim)
        self.initial = self.x.copy()  # the start cloud, kept for peers fed the same start (benchmark)
        self.logw = np.zeros(self.n)
        if prior_mean is not None:
            self.model.set_prior(prior_mean, prior_cov)

    # -- the skeleton ---------------------------------------------------------------------------
    def predict(self):
        """Draw x_k from the model's transition."""
        self.x = self.model.transition(self.x, self.k, self.rng)

    def propose(self, z):
        """Draw the new particles; returns log p(x | x_prev) - log q(x) per particle (0: the prior is the proposal)."""
        self.predict()
        return 0.0

    def loglik(self, x: np.ndarray, z) -> np.ndarray:
        return self.model.loglik(x, z, self.k)

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
        self.last_idx = idx
        return idx

    def update(self, z) -> bool:
        """One measurement; False if it is unusable or no particle can explain it (weights untouched)."""
        if not self.model.usable(z):
            self.skipped += 1
            self.resampled = False
            return False
        self.k += 1
        self.model.observe(z)
        self.x_prev = self.x
        correction = self.propose(z)
        self.prev_logw = self.logw
        self.last_ll = ll = self.loglik(self.x, z)
        new = self.logw + ll + correction
        top = new.max()
        if not np.isfinite(top):
            self.skipped += 1
            self.resampled = False
            return False
        self.logw = new - top
        self.after_weight(z)
        self.resampled = self.should_resample()
        if self.resampled:
            self.resample()
            self.after_resample(z)
        return True

    # -- hooks ----------------------------------------------------------------------------------
    def after_weight(self, z):
        """Called after weighting with the new measurement (the fish school runs here in the paper)."""

    def after_resample(self, z):
        """Called after resampling (move steps that restore diversity run here)."""

    # -- output ---------------------------------------------------------------------------------
    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean (AFSA eq. 25) and weighted covariance of the cloud."""
        w = self.weights
        mean = w @ self.x
        d = self.x - mean
        cov = (w[:, None] * d).T @ d
        return mean, cov


class ReplacesResampling:
    """Mixin for filters whose own step stands in for resampling (DE, the genetic algorithm): they never
    resample, and every step starts from equal weights, as after a resampling."""

    def propose(self, z):
        self.logw = np.zeros(self.n)
        return super().propose(z)

    def should_resample(self) -> bool:
        return False
