"""The particle-filter skeleton every algorithm plugs into: predict, log-domain weights, ESS, resampling,
estimate and covariance, over any StateSpaceModel (the emitter problem, or a paper's benchmark model).

One `update(z)` is one measurement: propose (by default: predict with the model's transition) -> weight
-> `after_weight` hook -> resample when `should_resample()` -> `after_resample` hook. A filter module overrides
these steps (propose, after_weight, should_resample, resample, after_resample, predict) and, when it keeps state
that depends on the whole posterior, initialise and invalidate.
A filter names the model capabilities it needs in `needs` (models/base.py); `make_filter` checks them.
The robustness layer's moves (log_target, rejuvenate, reweight, replace_cloud) need a StaticPosterior model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from aoa_localizer.filters import moves
from aoa_localizer.filters.algorithm import GroupAccess
from aoa_localizer.filters.resampling import SCHEMES
from aoa_localizer.models.base import StateSpaceModel, StaticPosterior


@dataclass(frozen=True)
class FilterSettings(GroupAccess):
    """What a filter reads of the configuration: the skeleton's settings and the algorithms' settings groups (a
    filter reads only its own, as `self.cfg.<group>`), so a benchmark model needs no emitter settings."""

    groups: tuple[tuple[str, Any], ...]
    num_particles: int = 100
    resampling: str = "systematic"
    ess_threshold: float = 0.5
    move_sweeps: int = 3

    @classmethod
    def of(cls, cfg: Any) -> FilterSettings:
        """The settings filters read from a LocalizerConfig (any object with these fields)."""
        return cls(cfg.groups, cfg.num_particles, cfg.resampling, cfg.ess_threshold, cfg.move_sweeps)


@dataclass(frozen=True)
class CloudSummary:
    """What a cloud's readers need, made once: normalised weights, ESS, weighted mean and covariance, whether all
    of them and the particles are finite, with the particle and log-weight arrays they were made from."""

    x: np.ndarray
    logw: np.ndarray
    weights: np.ndarray
    ess: float
    mean: np.ndarray
    cov: np.ndarray
    finite: bool

    @classmethod
    def of(cls, x: np.ndarray, logw: np.ndarray) -> CloudSummary:
        w = np.exp(logw - logw.max())
        total = w.sum()
        ess = float(total**2 / np.dot(w, w))  # (sum w)^2 / sum w^2, before normalising
        w /= total
        mean = w @ x
        d = x - mean
        cov = (w[:, None] * d).T @ d
        for a in (x, logw, w, mean, cov):  # the cloud too: changed in place, it would no longer match its summary
            a.flags.writeable = False
        finite = bool(np.isfinite(x).all()) and all(map(math.isfinite, (*mean.tolist(), *cov.ravel().tolist())))
        return cls(x, logw, w, ess, mean, cov, finite)


class ParticleFilter:
    """Bootstrap skeleton; subclasses change behaviour only through the hooks."""

    name = "base"
    needs: tuple[type, ...] = ()  # model capabilities (protocols of models/base.py) beyond StateSpaceModel

    def __init__(self, settings: FilterSettings, rng: np.random.Generator, model: StateSpaceModel):
        self.cfg = settings
        self.rng = rng
        self.model = model
        self.n = settings.num_particles
        self.resampler = SCHEMES[settings.resampling]
        self.x = np.zeros((self.n, self.model.dim))
        self.logw = np.zeros(self.n)
        self.k = 0  # measurements taken
        self.x_prev = self.x  # particles before the newest prediction (ESPF's parents)
        self.prev_logw = self.logw  # weights before the newest measurement (for hooks that re-weight)
        self.last_ll = np.zeros(self.n)  # log-likelihood of the newest measurement at the predicted particles
        self.last_idx = np.arange(self.n)  # ancestors chosen by the last resampling
        self.resampled = False  # whether the last update resampled
        self.skipped = 0  # updates refused: unusable measurement, or no particle could explain it
        self._summary: CloudSummary | None = None

    # -- set-up -------------------------------------------------------------------------------
    def initialise(self, particles: np.ndarray, prior_mean=None, prior_cov=None, logw: np.ndarray | None = None,
                   taken: int = 0):
        """Start from given particles (equal weights, or the log weights `logw`) after `taken` measurements the
        model already holds; the emitter model also takes a Gaussian prior."""
        self.x = np.array(particles, dtype=float).reshape(self.n, self.model.dim)
        self.logw = np.zeros(self.n) if logw is None else np.array(logw, dtype=float).reshape(self.n)
        self.k = taken
        if prior_mean is not None:
            self.posterior_model.set_prior(prior_mean, prior_cov)

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
        """Normalised weights (read-only: kept until the filter's particles or weights are replaced)."""
        return self._cloud_summary().weights

    def ess(self) -> float:
        """(sum w)^2 / sum w^2 of the weights: 1 / sum(w^2) of the normalised ones."""
        return self._cloud_summary().ess

    def finite(self) -> bool:
        """Whether the particles, their weighted mean and covariance are all finite (a diverged cloud is not)."""
        return self._cloud_summary().finite

    def _cloud_summary(self) -> CloudSummary:
        """Weights, ESS, mean and covariance of the cloud, made once per cloud: a step reads them several times
        (health, divergence test, estimate). The particles and weights are only ever replaced, never changed in
        place, so the arrays' identity says whether the summary still holds; the summary keeps them alive."""
        s = self._summary
        if s is None or s.x is not self.x or s.logw is not self.logw:
            s = self._summary = CloudSummary.of(self.x, self.logw)
        return s

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

    @property
    def posterior_model(self) -> StaticPosterior:
        """The model as a StaticPosterior: filters that need one say so in `needs`; a prior and the safety moves
        need one too (the emitter model is)."""
        return cast(StaticPosterior, self.model)

    # -- moves on the posterior over all kept points (models with a `log_posterior`: the emitter) -----------
    def log_target(self, x: np.ndarray, of: np.ndarray | None = None) -> np.ndarray:
        """The posterior the safety moves keep invariant: the model's, over its kept points (the same for every
        particle, so `of`, whose moves the rows are, is not read)."""
        return self.posterior_model.log_posterior(x)

    def rejuvenate(self, sweeps: int, proposal=None):
        """`sweeps` random-walk MH moves scaled by the cloud, then one independence MH move from `proposal`
        (a ModeProposal) if given. Each leaves the posterior invariant, so the weighted cloud stays a sample of
        it; the weights are untouched. Returns the share of accepted moves."""
        target = self.log_target(self.x)
        accepted, tried = 0, 0
        chol = moves.cloud_chol(self.estimate()[1], moves.RW_SCALE)
        for _ in range(sweeps):
            self.x, target, a = moves.random_walk(self.x, target, self.log_target, self.rng, chol)
            accepted, tried = accepted + a, tried + self.n
        if proposal is not None:
            self.x, target, a = moves.independence_from(self.x, target, self.log_target, self.rng, proposal)
            accepted, tried = accepted + a, tried + self.n
        self.invalidate()
        return accepted / max(tried, 1)

    def reweight(self, log_ratio: np.ndarray):
        """Multiply the weights by exp(log_ratio) (the target changed: new noise model, new outlier rate)."""
        new = self.logw + log_ratio
        top = new.max()
        if np.isfinite(top):
            self.logw = new - top
        self.invalidate()

    def replace_cloud(self, particles: np.ndarray):
        """Equal-weight particles from elsewhere (a start or re-start from the global search)."""
        self.x = np.array(particles, float).reshape(self.n, self.model.dim)
        self.logw = np.zeros(self.n)
        self.invalidate()

    def invalidate(self):
        """The particles or the target changed outside the filter's own step: drop cached values."""

    # -- hooks ----------------------------------------------------------------------------------
    def after_weight(self, z):
        """Called after weighting with the new measurement (the fish school runs here in the paper)."""

    def after_resample(self, z):
        """Called after resampling (move steps that restore diversity run here)."""

    # -- output ---------------------------------------------------------------------------------
    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean (AFSA eq. 25) and weighted covariance of the cloud (read-only arrays)."""
        s = self._cloud_summary()
        return s.mean, s.cov


class ReplacesResampling:
    """Mixin for filters whose own step stands in for resampling (DE, the genetic algorithm): they never
    resample, and every step starts from equal weights, as after a resampling."""

    def propose(self, z):
        self.logw = np.zeros(self.n)
        return super().propose(z)

    def should_resample(self) -> bool:
        return False
