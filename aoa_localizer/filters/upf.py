"""The unscented-proposal family (UPF-DE paper, Li Hongwei et al. 2011): UPF, UPF-DE and PF-DE.

* `upf`: each particle carries a covariance; a UKF step (predict from the particle, update with the
  newest measurement) gives its Gaussian proposal N(m_i, S_i); the draw is weighted
  w = L(z|x) p(x|x_prev) / q(x), then resampled at every step.
* `upfde`: the same proposal and weight, then differential evolution (F1, F2, Cr, G) with the weights as
  fitness instead of resampling; a trial replacing particle i is scored with particle i's own
  x_prev and proposal. The evolved particles are the next prior; the next step starts from equal weights.
* `pfde`: the transition as proposal (fitness = likelihood), then the same evolution.
The estimate is the mean weighted by the final fitness. These are the `paper` variants (`upf.variant`,
`de.variant`). The paper never says what a DE trial's fitness is: `de.fitness: posterior` (default) scores it by
L p, the path posterior; `ratio` by the importance ratio L p / q, which is unbounded (DE then maximises a
ratio and walks particles out of their proposal: the emitter runs away).

The `mcmc` variants (default, the emitter) are resample-move on the static posterior: `upf` proposes from the
UKF's Gaussian (the cloud before the newest point, updated with it, widened) as an independence MH move, plus a
random walk; `upfde` runs DE-MC (ter Braak: x_i + F2 (x_r1 - x_r2) on the paper's crossover mask, a tiny
jitter, Metropolis acceptance) and the same independence move; `pfde` DE-MC alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aoa_localizer.core.spec import variant_choice
from aoa_localizer.filters import moves
from aoa_localizer.filters.algorithm import Algorithm
from aoa_localizer.filters.base import ParticleFilter, ReplacesResampling
from aoa_localizer.filters.de import DeConfig, evolve
from aoa_localizer.filters.moves import RW_SCALE
from aoa_localizer.filters.resample_move import MoveKernel
from aoa_localizer.filters.ukf import BatchedUKF, gauss_logpdf
from aoa_localizer.models.base import TransitionDensity, UnscentedForm

WIDEN = 1.5  # the UKF's Gaussian is widened before it proposes: a bearing posterior has heavier tails
JITTER = 0.01  # DE-MC's jitter, in standard deviations of the cloud


@dataclass(frozen=True)
class UpfConfig:
    """The unscented PF on the emitter: `mcmc` (the UKF's Gaussian as an independence MH proposal) or `paper`."""

    variant: str = variant_choice("UPF")


class UkfProposalFilter(ParticleFilter):
    """The per-particle unscented proposal (shared by upf and upfde)."""

    needs = (UnscentedForm, TransitionDensity)

    def initialise(self, particles, prior_mean=None, prior_cov=None, logw=None, taken=0):
        super().initialise(particles, prior_mean, prior_cov, logw, taken)
        d = self.model.dim
        p0 = getattr(self.model, "p0", None)
        cov = np.diag(p0) if p0 is not None else np.atleast_2d(np.cov(self.x.T)) + 1e-6 * np.eye(d)
        self.P = np.broadcast_to(cov, (self.n, d, d)).copy()
        self.ukf = BatchedUKF(d)

    def propose(self, z):
        f, Q, h, R, angles, zvec = self.model.ukf(self.k, z)
        m, P = self.ukf.predict(self.x, self.P, f, Q)
        m, P = self.ukf.update(m, P, h, R, zvec, angles)
        L = np.linalg.cholesky(P + 1e-12 * np.eye(P.shape[-1]))
        self.x = m + np.einsum("nij,nj->ni", L, self.rng.standard_normal(m.shape))
        self.P, self.q_mean = P, m
        return self.model.transition_logpdf(self.x, self.x_prev, self.k) - gauss_logpdf(self.x, m, P)

    def fitness(self, x, z):
        """A trial's log fitness as particle i's draw: L p (`de.fitness: posterior`) or L p / q (`ratio`)."""
        path = self.loglik(x, z) + self.model.transition_logpdf(x, self.x_prev, self.k)
        return path if self.cfg.de.fitness == "posterior" else path - gauss_logpdf(x, self.q_mean, self.P)


class UpfFilter(UkfProposalFilter):
    name = "upf"

    def should_resample(self) -> bool:
        return True

    def resample(self):
        idx = super().resample()
        self.P = self.P[idx]
        return idx


class DeInsteadOfResampling(ReplacesResampling):
    """Mixin: evolve the weighted particles instead of resampling."""

    def after_weight(self, z):
        fit = np.where(np.isfinite(self.logw), self.logw, -np.inf)
        x, fit = evolve(self.x, fit, lambda trial: self.fitness(trial, z), self.cfg.de, self.rng)
        self.x = x
        self.logw = fit - fit.max()


class UpfDeFilter(DeInsteadOfResampling, UkfProposalFilter):
    name = "upfde"


class PfDeFilter(DeInsteadOfResampling, ParticleFilter):
    name = "pfde"

    def fitness(self, x, z):
        """With the transition as proposal, p(x|x_prev)/q(x) = 1: the fitness is the likelihood."""
        return self.loglik(x, z)


class UkfGaussianMoves(MoveKernel):
    """Moves that may use the UKF's Gaussian of the posterior after the newest point."""

    needs = (UnscentedForm,)

    def __init__(self):
        self.ukf_mean = np.zeros(0)  # the UKF's Gaussian at the last resampling (prepare)
        self.ukf_chol = np.zeros((0, 0))

    def prepare(self, f, z):
        """The UKF's Gaussian: the weighted cloud before the newest point, updated with it by one UKF step."""
        d = f.model.dim
        w = np.exp(f.prev_logw - f.prev_logw.max())
        w /= w.sum()
        m0 = w @ f.x_prev
        dev = f.x_prev - m0
        P0 = (w[:, None] * dev).T @ dev + moves.SPREAD_FLOOR_M2 * np.eye(d)
        _, _, h, R, angles, zvec = f.model.ukf(f.k, z)
        ukf = BatchedUKF(d)
        m, P = ukf.update(m0[None, :], P0[None, :, :], h, R, zvec, angles)
        self.ukf_mean = m[0]
        try:
            self.ukf_chol = moves.cloud_chol(P[0], WIDEN)
        except np.linalg.LinAlgError:  # a degenerate update: the cloud's own spread proposes instead
            self.ukf_mean, self.ukf_chol = m0, f.chol(WIDEN)

    def independence(self, f, target):
        return moves.independence(f.x, target, f.log_target, f.rng, self.ukf_mean, self.ukf_chol)

    def de_mc(self, f, x, target):
        de = f.cfg.de
        return moves.de_mc(x, target, f.log_target, f.rng, de.f2, de.cr, f.chol(JITTER))


class UpfMoves(UkfGaussianMoves):
    """`upf.variant: mcmc`: the UKF's Gaussian as an independence proposal, then a random walk."""

    name = "upf"

    def sweep(self, f, target, z):
        x, target, a1 = self.independence(f, target)
        x, target, a2 = moves.random_walk(x, target, f.log_target, f.rng, f.chol(RW_SCALE))
        return x, target, a1 + a2, 2 * f.n


class UpfDeMoves(UkfGaussianMoves):
    """`de.variant: mcmc` for upfde: DE-MC, then the UKF independence move."""

    name = "upfde"

    def sweep(self, f, target, z):
        x, target, a1 = self.independence(f, target)
        x, target, a2 = self.de_mc(f, x, target)
        return x, target, a1 + a2, 2 * f.n


class PfDeMoves(MoveKernel):
    """`de.variant: mcmc` for pfde: DE-MC on the posterior."""

    name = "pfde"

    def sweep(self, f, target, z):
        de = f.cfg.de
        x, target, accepted = moves.de_mc(f.x, target, f.log_target, f.rng, de.f2, de.cr, f.chol(JITTER))
        return x, target, accepted, f.n


ALGORITHMS = (
    Algorithm("upfde", "UKF proposal + differential evolution", "de", DeConfig, UpfDeFilter, UpfDeMoves),
    Algorithm("upf", "unscented PF", "upf", UpfConfig, UpfFilter, UpfMoves),
    Algorithm("pfde", "PF + differential evolution", "de", DeConfig, PfDeFilter, PfDeMoves),
)
