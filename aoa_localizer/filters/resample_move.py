"""The emitter variant (`<filter>.variant: mcmc`, the default) shared by every paper's filter: resample-move.

The emitter is static, so there is no prediction noise: each observation point re-weights the cloud by its
likelihood, the cloud is resampled when its effective sample size falls under the threshold, and then
`move_sweeps` sweeps of the filter's own operator, made a Metropolis-Hastings move on the posterior over all
kept points (moves.py), restore diversity without changing the law. The weighted cloud stays a sample of the
posterior, so its covariance is an honest ellipse, whatever operator a paper brings.
"""
from __future__ import annotations

import numpy as np

from aoa_localizer.filters import moves
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.models.base import StaticPosterior


class ResampleMove(ParticleFilter):
    """Static emitter, re-weight, resample on low ESS, then `sweep()` (each filter's operator) `sweeps` times."""

    needs: tuple[type, ...] = (StaticPosterior,)

    def __init__(self, settings, rng, model):
        super().__init__(settings, rng, model)
        self.spread = np.eye(model.dim)  # the weighted cloud's covariance just before the last resampling
        self.acceptance = float("nan")  # share of accepted moves in the last move stage
        self.sweeps = settings.move_sweeps
        # False: a resampling's `sweeps` are made right after it. True: none there; whoever drives the filter makes
        # them later with move() (the engine's Scheduler, `scheduling: realtime`: a bounded step). Any sweep keeps the
        # current posterior invariant, so when it is made changes no law.
        self.deferred = False
        self.last_z = None  # the newest point, for sweeps made after it

    def predict(self):
        """The emitter does not move: no process noise (the moves keep the cloud diverse)."""

    def resample(self) -> np.ndarray:
        # The weighted cloud before resampling is the better picture of the posterior's spread.
        self.spread = self.estimate()[1]
        return super().resample()

    def after_resample(self, z):
        self.last_z = z
        self.prepare(z)
        if not self.deferred:
            self.move(self.sweeps)

    def chol(self, scale: float = 1.0) -> np.ndarray:
        """Cholesky factor of scale^2 times the cloud's spread (floored)."""
        return moves.cloud_chol(self.spread, scale)

    def update(self, z) -> bool:
        ok = super().update(z)
        if ok:
            self.last_z = z
        return ok

    def prepare(self, z):
        """Before a resampling's sweeps: what they share (an operator may build its proposal from the newest point
        `z`)."""

    def move(self, count: int):
        """`count` sweeps of the filter's operator on the posterior, given the newest point (None before one); the
        weights (equal after a resampling) stay."""
        self._sweeps(count, self.last_z)

    def _sweeps(self, count: int, z):
        target = self.log_target(self.x)
        accepted = tried = 0
        for _ in range(count):
            self.x, target, a, t = self.sweep(target, z)
            accepted, tried = accepted + a, tried + t
        self.acceptance = accepted / max(tried, 1)
        self.targets_known(target)

    def sweep(self, target: np.ndarray, z) -> tuple[np.ndarray, np.ndarray, int, int]:
        """One sweep of the operator: (particles, their log posterior, moves accepted, moves tried)."""
        raise NotImplementedError
