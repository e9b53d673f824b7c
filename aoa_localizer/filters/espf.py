"""ESPF: the particle filter based on evolution sampling (Hu, Pan et al. 2009, sec. 3).

`espf.variant: paper`. After the ordinary resampling: take each resampled particle's parent at k-1 ("MCMC
pre-sampling"), pair the parents at random and cross them with simulated binary crossover (eqs. 10-11),
propagate the children through the state model (eq. 12) and weight them by their normalised likelihood
(eq. 13). The N resampled particles, with the weight resampling left them (1/N: "the weights recorded after
resampling"), and the N children with their normalised likelihoods form a pool of 2N from which N go on,
with equal weights. `espf.selection: draw` (default) draws the N from the pool in proportion to the weights
(systematic); `top` keeps the N largest. The paper says "select N"; `top` with every resampled particle at
1/N breaks the ties by position, and as the resampled block sits in ancestor order that would cull the tail of
the block at every step.

`espf.variant: mcmc` (default, the emitter): resample-move with SBX as a pair move accepted with
beta^d pi(c1) pi(c2) / (pi(x_i) pi(x_j)) (moves.pair_scale) plus a small random-walk MH step (SBX keeps each
pair's midpoint, so alone it cannot spread duplicates).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aoa_localizer.core.spec import choice, param, variant_choice
from aoa_localizer.filters import moves
from aoa_localizer.filters.algorithm import Algorithm
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.resample_move import MoveKernel
from aoa_localizer.filters.resampling import systematic

SMALL_STEP = 0.5  # the small random-walk step after the pair move, in standard deviations of the cloud


@dataclass(frozen=True)
class EspfConfig:
    """ESPF settings: the SBX distribution index lambda (any non-negative real in the paper; docs/seed_tables.md)."""

    variant: str = variant_choice("ESPF")
    sbx_lambda: float = param(2.0, "ESPF: distribution index of the simulated binary crossover (larger: children "
                              "nearer their parents)", low=0.0, high=100.0)
    selection: str = choice("draw", ("draw", "top"), "ESPF paper variant: `draw` N of the 2N pool by weight "
                            "(default), or `top`: the N largest weights (ties broken by position)")


def sbx_beta(u: np.ndarray, lam: float) -> np.ndarray:
    """SBX spread factor: (2u)^(1/(lambda+1)) for u <= 0.5, else (1/(2(1-u)))^(1/(lambda+1))."""
    u = np.asarray(u, float)
    e = 1.0 / (lam + 1.0)
    with np.errstate(divide="ignore"):
        return np.where(u <= 0.5, (2.0 * u) ** e, (1.0 / (2.0 * (1.0 - u))) ** e)


def sbx_scale(rng: np.random.Generator, m: int, lam: float) -> np.ndarray:
    """m draws of the SBX spread factor beta (u ~ U(0, 1)); its law has p(1/beta) = beta^2 p(beta), which makes
    the pair move of filters/moves.py reversible."""
    return sbx_beta(rng.random(m), lam)


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
        pool_w = np.concatenate([np.full(n, 1.0 / n), cand_w])
        keep = top_n(pool_w, n) if self.cfg.espf.selection == "top" else systematic(pool_w / pool_w.sum(), rng, n)
        self.x = pool[keep]
        self.logw = np.zeros(n)


class EspfMoves(MoveKernel):
    """`espf.variant: mcmc`: SBX pair moves and a small random walk, both MH on the posterior."""

    name = "espf"

    def sweep(self, f, target, z):
        lam, rng = f.cfg.espf.sbx_lambda, f.rng
        x, target, crossed = moves.pair_scale(f.x, target, f.log_target, rng, lambda m: sbx_scale(rng, m, lam))
        x, target, walked = moves.random_walk(x, target, f.log_target, rng, f.chol(SMALL_STEP))
        return x, target, crossed + walked, 2 * f.n


ALGORITHMS = (Algorithm("espf", "evolution sampling", "espf", EspfConfig, EspfFilter, EspfMoves),)
