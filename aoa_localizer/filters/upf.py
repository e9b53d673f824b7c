"""The unscented-proposal family (UPF-DE paper, Li Hongwei et al. 2011): UPF, UPF-DE and PF-DE.

* `upf`: each particle carries a covariance; a UKF step (predict from the particle, update with the
  newest measurement) gives its Gaussian proposal N(m_i, S_i); the draw is weighted
  w = L(z|x) p(x|x_prev) / q(x), then resampled at every step.
* `upfde`: the same proposal and weight, then differential evolution (F1, F2, Cr, G) with the weights as
  fitness instead of resampling; a trial replacing particle i is scored with particle i's own
  x_prev and proposal. The evolved particles are the next prior; the next step starts from equal weights.
* `pfde`: the transition as proposal (fitness = likelihood), then the same evolution.
The estimate is the mean weighted by the final fitness.
"""
from __future__ import annotations

import numpy as np

from aoa_localizer.filters.base import ParticleFilter, ReplacesResampling
from aoa_localizer.filters.de import evolve
from aoa_localizer.filters.ukf import BatchedUKF, gauss_logpdf
from aoa_localizer.models.base import TransitionDensity, UnscentedForm


class UkfProposalFilter(ParticleFilter):
    """The per-particle unscented proposal (shared by upf and upfde)."""

    needs = (UnscentedForm, TransitionDensity)

    def initialise(self, particles, prior_mean=None, prior_cov=None):
        super().initialise(particles, prior_mean, prior_cov)
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
        """The full importance weight of x as particle i's draw (log)."""
        return (self.loglik(x, z) + self.model.transition_logpdf(x, self.x_prev, self.k)
                - gauss_logpdf(x, self.q_mean, self.P))


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
