"""The emitter variant (`<filter>.variant: mcmc`, the default) shared by every paper's filter: resample-move.

The emitter is static, so there is no prediction noise: each observation point re-weights the cloud by its
likelihood, the cloud is resampled when its effective sample size falls under the threshold, and then
`move_sweeps` sweeps of the paper's operator (its MoveKernel), made a Metropolis-Hastings move on the posterior over
all kept points (moves.py), restore diversity without changing the law. The weighted cloud stays a sample of the
posterior, so its covariance is an honest ellipse, whatever operator a paper brings. One ResampleMove class serves
every algorithm: a filter module gives only its kernel. While the receiver's noise is latent (a marginal over
hypotheses), the sweeps run on the joint of place and hypothesis (a Gibbs draw of each particle's, then the
operator given it), whose looks cost one hypothesis each.
"""
from __future__ import annotations

from typing import cast

import numpy as np

from aoa_localizer.filters import moves
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.models.base import LatentNoise, StaticPosterior


class MoveKernel:
    """One paper's operator as moves that keep the posterior over all kept points: what a ResampleMove sweeps with.
    A filter module subclasses it once and registers it as its `mcmc` variant; one instance per filter holds what
    its sweeps share."""

    name = "base"
    needs: tuple[type, ...] = ()  # model capabilities beyond the StaticPosterior every move needs
    every_point = False  # resample at every point (a selection step), not only on a low ESS

    def sweeps(self, settings) -> int:
        """Sweeps after each resampling."""
        return settings.move_sweeps

    def prepare(self, f: ResampleMove, z):
        """Before a resampling's sweeps: what they share (a proposal built from the newest point `z`)."""

    def sweep(self, f: ResampleMove, target: np.ndarray, z) -> tuple[np.ndarray, np.ndarray, int, int]:
        """One sweep on `f`'s cloud: (particles, their log posterior, moves accepted, moves tried)."""
        raise NotImplementedError


class ResampleMove(ParticleFilter):
    """Static emitter, re-weight, resample on low ESS, then `sweeps` sweeps of the kernel (the paper's operator)."""

    needs: tuple[type, ...] = (StaticPosterior,)

    def __init__(self, settings, rng, model, kernel: MoveKernel, deferred: bool = False):
        super().__init__(settings, rng, model)
        self.kernel = kernel
        self.name = kernel.name
        self.spread = np.eye(model.dim)  # the weighted cloud's covariance just before the last resampling
        self.acceptance = float("nan")  # share of accepted moves in the last move stage
        self.sweeps = kernel.sweeps(settings)
        # False: a resampling's `sweeps` are made right after it. True: none there; whoever drives the filter makes
        # them later with move() (the engine's Scheduler, `scheduling: realtime`: a bounded step). Any sweep keeps the
        # current posterior invariant, so when it is made changes no law.
        self.deferred = deferred
        self.last_z = None  # the newest point, for sweeps made after it
        self._given: np.ndarray | None = None  # each particle's noise hypothesis during a sweep that drew them

    def predict(self):
        """The emitter does not move: no process noise (the moves keep the cloud diverse)."""

    def should_resample(self) -> bool:
        return self.kernel.every_point or super().should_resample()

    def resample(self) -> np.ndarray:
        # The weighted cloud before resampling is the better picture of the posterior's spread.
        self.spread = self.estimate()[1]
        return super().resample()

    def after_resample(self, z):
        self.last_z = z
        self.kernel.prepare(self, z)
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

    def move(self, count: int, part: np.ndarray | None = None):
        """`count` sweeps of the filter's operator on the posterior, given the newest point (None before one); the
        weights (equal after a resampling) stay. `part`: only these particles move (indices; the operator sees them
        as its cloud): each particle's move keeps the posterior invariant whichever others move, so a sweep can be
        made a part at a time."""
        if part is None:
            self._sweeps(count, self.last_z)
            return
        cloud, n = self.x, self.n
        self.x, self.n = cloud[part], len(part)
        try:
            self._sweeps(count, self.last_z)
            moved = self.x
        finally:
            self.x, self.n = cloud.copy(), n
        self.x[part] = moved
        self.invalidate()

    def _sweeps(self, count: int, z):
        joint = self.model.hypotheses_log_joint(self.x) if isinstance(self.model, LatentNoise) else None
        if joint is not None:
            self._sweeps_with_noise(count, z, joint)
            return
        target = self.log_target(self.x)
        accepted = tried = 0
        for _ in range(count):
            self.x, target, a, t = self.sweep(target, z)
            accepted, tried = accepted + a, tried + t
        self.acceptance = accepted / max(tried, 1)
        self.invalidate()

    def _sweeps_with_noise(self, count: int, z, joint: np.ndarray):
        """The sweeps on the posterior of place and noise hypothesis together, whose marginal in the place is the
        filter's target: each draws every particle's hypothesis given its place (Gibbs, from `joint`, the (N, H)
        log joint at the particles), then moves the places given their hypotheses, a look costing one hypothesis
        instead of all. The draws and the moves each keep the joint, so the places stay a sample of the marginal."""
        model = cast(LatentNoise, self.model)
        rows = np.arange(self.n)
        accepted = tried = 0
        joint_at = self.x
        for sweep in range(count):
            if sweep:  # the joint again where the last sweep moved a particle
                moved = np.any(self.x != joint_at, axis=1)
                if moved.any():
                    joint[moved] = model.hypotheses_log_joint(self.x[moved])
                joint_at = self.x
            self._given = moves.categorical(joint, self.rng)
            try:
                self.x, _, a, t = self.sweep(joint[rows, self._given], z)
            finally:
                self._given = None
            accepted, tried = accepted + a, tried + t
        self.acceptance = accepted / max(tried, 1)
        self.invalidate()

    def log_target(self, x: np.ndarray, of: np.ndarray | None = None) -> np.ndarray:
        """The posterior the moves keep invariant; while a sweep holds each particle's noise hypothesis, the joint
        of place and hypothesis, each row at the hypothesis of the particle `of` names (None: in order)."""
        if self._given is None:
            return super().log_target(x, of)
        given = self._given if of is None else self._given[of]
        return cast(LatentNoise, self.model).log_posterior_given(x, given)

    def sweep(self, target: np.ndarray, z) -> tuple[np.ndarray, np.ndarray, int, int]:
        """One sweep of the kernel: (particles, their log posterior, moves accepted, moves tried)."""
        return self.kernel.sweep(self, target, z)
