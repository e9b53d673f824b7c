"""ESPF: the particle filter based on evolution sampling (Hu, Pan et al. 2009, sec. 3).

After the ordinary resampling: take each resampled particle's parent at k-1 ("MCMC pre-sampling"),
pair the parents at random and cross them with simulated binary crossover (eqs. 10-11), propagate the
children through the state model (eq. 12) and weight them by their normalised likelihood (eq. 13).
The N resampled particles, with the weight resampling left them (1/N: "the weights recorded after
resampling"), and the N children with their normalised likelihoods form a pool of 2N; the N with the
largest weights go on, with equal weights. So a child replaces a resampled particle when its likelihood
is above the children's average. (Reading the recorded weights as the pre-resampling ones instead lets
the copies of one heavy particle fill the whole selection; measured in docs/seed_tables.md.)
"""
from __future__ import annotations

import numpy as np

from aoa_localizer.filters.base import ParticleFilter


def sbx_beta(u: np.ndarray, lam: float) -> np.ndarray:
    """SBX spread factor: (2u)^(1/(lambda+1)) for u <= 0.5, else (1/(2(1-u)))^(1/(lambda+1))."""
    u = np.asarray(u, float)
    e = 1.0 / (lam + 1.0)
    with np.errstate(divide="ignore"):
        return np.where(u <= 0.5, (2.0 * u) ** e, (1.0 / (2.0 * (1.0 - u))) ** e)


def sbx_children(xi: np.ndarray, xj: np.ndarray, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 10-11: 0.5[(1+b) xi + (1-b) xj] and 0.5[(1-b) xi + (1+b) xj] (beta per pair, all dimensions)."""
    b = np.asarray(beta, float)[:, None]
    return 0.5 * ((1 + b) * xi + (1 - b) * xj), 0.5 * ((1 - b) * xi + (1 + b) * xj)


def top_n(weights: np.ndarray, n: int) -> np.ndarray:
    """Indices of the n largest weights (ties broken by position, so the choice is reproducible)."""
    return np.argsort(-weights, kind="stable")[:n]


class EspfFilter(ParticleFilter):
    name = "espf"

    def should_resample(self) -> bool:
        return True  # the paper resamples at every step, then evolves

    def after_resample(self, z):
        rng, n, idx = self.rng, self.n, self.last_idx
        parents = self.x_prev[idx]
        order = rng.permutation(n)
        if n % 2:  # an odd fish out pairs with a random partner
            order = np.append(order, rng.integers(0, n))
        i, j = order[0::2], order[1::2]
        beta = sbx_beta(rng.random(i.size), self.cfg.espf.sbx_lambda)
        c1, c2 = sbx_children(parents[i], parents[j], beta)
        children = self.model.transition(np.concatenate([c1, c2])[:n], self.k, rng)
        ll = self.loglik(children, z)
        cand_w = np.exp(ll - ll.max()) if np.isfinite(ll.max()) else np.zeros(n)
        cand_w = cand_w / cand_w.sum() if cand_w.sum() > 0 else cand_w
        pool = np.concatenate([self.x, children])
        keep = top_n(np.concatenate([np.full(n, 1.0 / n), cand_w]), n)
        self.x = pool[keep]
        self.logw = np.zeros(n)
