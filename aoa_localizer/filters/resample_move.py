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
        # 0: all `sweeps` right after the resampling; n (`scheduling: realtime`, a bounded step): none there, owed,
        # and at most n at each following point until all are made, unless pay_owed() (idle time) made them first.
        # Any sweep keeps the current posterior invariant.
        self.sweeps_per_point = 0
        self.owed = 0
        self.last_z = None  # the newest point, for sweeps made between points

    def predict(self):
        """The emitter does not move: no process noise (the moves keep the cloud diverse)."""

    def resample(self) -> np.ndarray:
        # The weighted cloud before resampling is the better picture of the posterior's spread.
        self.spread = self.estimate()[1]
        return super().resample()

    def after_resample(self, z):
        self.move(z)

    def chol(self, scale: float = 1.0) -> np.ndarray:
        """Cholesky factor of scale^2 times the cloud's spread (floored)."""
        return moves.cloud_chol(self.spread, scale)

    def update(self, z) -> bool:
        ok = super().update(z)
        if ok:
            self.last_z = z
        if ok and not self.resampled and self.owed:
            self._sweeps(min(self.owed, self.sweeps_per_point), z)
        return ok

    def pay_owed(self) -> bool:
        """One owed sweep now (the node's idle time), so the next point need not make it; False if none is owed."""
        if not self.owed or self.last_z is None:
            return False
        self._sweeps(1, self.last_z)
        return True

    def move(self, z):
        """`sweeps` sweeps of the filter's operator on the posterior; the weights (equal after resampling) stay.
        `z`: the newest point (an operator may build its proposal from it). With `sweeps_per_point`, none now: they
        are owed, made by pay_owed() between points or `sweeps_per_point` at each following point; whatever the
        last resampling still owed is made now: resamplings that come faster than the debt is paid get all their
        sweeps, as without the spreading (the cloud would otherwise collapse onto a few copies)."""
        if not self.sweeps_per_point:
            self.owed = self.sweeps
            self._sweeps(self.sweeps, z)
            return
        unpaid = self.owed
        self.owed += self.sweeps
        if unpaid:
            self._sweeps(unpaid, z)

    def _sweeps(self, count: int, z):
        self.owed -= count
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
