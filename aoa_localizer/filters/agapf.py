"""AGA-PF: the non-degenerate particle filter with an adaptive genetic algorithm (Wu Hao, Sun Xiaoyan 2016).

`agapf.variant: paper`. Each step: propagate, weight w = L(z|x), fitness = normalised weight (eq. 17);
roulette selection by fitness; arithmetic crossover of pairs with the adaptive probability pc of eq. 18
(f' the fitter parent); Gaussian mutation with the adaptive probability pm of eq. 19 (f the individual's own
fitness); no other resampling. The selection already used the newest likelihood, so the offspring carry equal
weights (weighting them by the likelihood again would count the newest measurement twice: every ellipse
over-confident).

The adaptive curves: A = 9.9034 is the constant of Kuang et al.'s adaptive sigmoid,
pc = pc1 - (pc1 - pc2) / (1 + exp(-A (2 (f' - f_avg) / (f_max - f_avg) - 1))); the "- 1" was lost in
eqs. 18-19 as printed. `agapf.curve: kuang` (default) restores it: continuous at f_avg (pc1), pc2 at f_max,
and the same form for pm (pm1 at the average, pm2 for the fittest: good individuals mutate less, as the text
says). `printed`: the equations as printed (pc jumps at f_avg; pm mirrored to fall, as the text intends).
The real-valued operators are ours: crossover children a x1 + (1-a) x2 and (1-a) x1 + a x2 with
a ~ U(0, 1); mutation adds N(0, s^2) with s the population's standard deviation per dimension.

`agapf.variant: mcmc` (default, the emitter): selection is the resampling (every point); the arithmetic
crossover, made reversible by adding its inverse (the half-difference scaled by s = 2a - 1 or by 1/s), and the
mutation are MH moves on the posterior, tried with the adaptive probabilities (fitness from the posterior,
f_avg and f_max fixed per sweep) and carrying them in the ratio; equal weights after the moves.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aoa_localizer.core.spec import choice, param, variant_choice
from aoa_localizer.filters import moves
from aoa_localizer.filters.algorithm import Algorithm
from aoa_localizer.filters.base import ParticleFilter, ReplacesResampling
from aoa_localizer.filters.moves import RW_SCALE
from aoa_localizer.filters.resample_move import MoveKernel


@dataclass(frozen=True)
class AgapfConfig:
    """AGA-PF's adaptive crossover and mutation probabilities (eqs. 18-19)."""

    variant: str = variant_choice("AGA-PF")
    curve: str = choice("kuang", ("kuang", "printed"), "AGA-PF: the adaptive curves of eqs. 18-19, `kuang` (with "
                        "the - 1 of Kuang et al.'s sigmoid: pc1 at the average fitness, pc2 at the best) or "
                        "`printed`")
    pc1: float = param(0.95, "AGA-PF: crossover probability below the average fitness", low=0.0, high=1.0)
    pc2: float = param(0.5, "AGA-PF: crossover probability floor for the fittest", low=0.0, high=1.0)
    pm1: float = param(0.07, "AGA-PF: mutation probability below the average fitness", low=0.0, high=1.0)
    pm2: float = param(0.001, "AGA-PF: mutation probability floor for the fittest", low=0.0, high=1.0)
    a: float = param(9.9034, "AGA-PF: steepness A of the adaptive curves", low=0.0, low_open=True, high=1e3)


def kuang(f, f_avg: float, f_max: float, p1: float, p2: float, a: float):
    """Kuang et al.'s adaptive sigmoid: p1 below the average fitness; above it p1 - (p1 - p2) /
    (1 + exp(-A (2 (f - f_avg) / (f_max - f_avg) - 1))), continuous at f_avg, p2 at f_max (to 1e-4 at A 9.9)."""
    f = np.asarray(f, float)
    span = max(f_max - f_avg, 1e-300)
    with np.errstate(over="ignore"):
        above = p1 - (p1 - p2) / (1 + np.exp(-a * (2 * (f - f_avg) / span - 1)))
    return np.where(f >= f_avg, above, p1)


def adaptive_pc(f_parent, f_avg: float, f_max: float, pc1: float, pc2: float, a: float, curve: str = "kuang"):
    """Eq. 18: pc1 below the average fitness; above it falls towards pc2 at f_max (`printed`: from
    (pc1+pc2)/2, a jump at f_avg)."""
    if curve == "kuang":
        return kuang(f_parent, f_avg, f_max, pc1, pc2, a)
    f = np.asarray(f_parent, float)
    span = max(f_max - f_avg, 1e-300)
    with np.errstate(over="ignore"):
        above = pc1 - (pc1 - pc2) / (1 + np.exp(-a * 2 * (f - f_avg) / span))
    return np.where(f >= f_avg, above, pc1)


def adaptive_pm(f, f_avg: float, f_max: float, pm1: float, pm2: float, a: float, curve: str = "kuang"):
    """Eq. 19: pm1 below the average; above it falls towards pm2 at f_max (`printed`: eq. 19 mirrored to fall as
    the text intends, from (pm1+pm2)/2)."""
    if curve == "kuang":
        return kuang(f, f_avg, f_max, pm1, pm2, a)
    f = np.asarray(f, float)
    span = max(f_max - f_avg, 1e-300)
    with np.errstate(over="ignore"):
        above = pm2 + (pm1 - pm2) / (1 + np.exp(a * 2 * (f - f_avg) / span))
    return np.where(f >= f_avg, above, pm1)


def arithmetic_scale(rng: np.random.Generator, m: int) -> np.ndarray:
    """s = 2a - 1 (a ~ U(0, 1)) or its inverse 1/s, half and half: the arithmetic crossover made reversible
    (its law has p(1/s) = s^2 p(s), as moves.pair_scale needs)."""
    s = rng.uniform(-1.0, 1.0, m)
    s = np.where(s == 0.0, 1e-12, s)
    return np.where(rng.random(m) < 0.5, s, 1.0 / s)


class AgaPfFilter(ReplacesResampling, ParticleFilter):
    name = "agapf"

    def after_weight(self, z):
        g, rng, n = self.cfg.agapf, self.rng, self.n
        fit = self.weights
        f_avg, f_max = float(fit.mean()), float(fit.max())
        parents = self.resampler(fit, rng)  # roulette selection by normalised weight
        x, pf = self.x[parents], fit[parents]
        order = rng.permutation(n)
        i, j = order[: n // 2], order[n // 2: 2 * (n // 2)]
        cross = rng.random(i.size) < adaptive_pc(np.maximum(pf[i], pf[j]), f_avg, f_max, g.pc1, g.pc2, g.a, g.curve)
        a = rng.random(i.size)[:, None]
        xi, xj = x[i], x[j]
        x[i] = np.where(cross[:, None], a * xi + (1 - a) * xj, xi)
        x[j] = np.where(cross[:, None], (1 - a) * xi + a * xj, xj)
        mutate = rng.random(n) < adaptive_pm(pf, f_avg, f_max, g.pm1, g.pm2, g.a, g.curve)
        spread = np.std(self.x, axis=0)
        x = np.where(mutate[:, None], x + spread * rng.standard_normal(x.shape), x)
        # Selection used the newest likelihood already: equal weights (weighting by it again counted it twice).
        self.x, self.last_ll = x, self.loglik(x, z)
        self.logw = np.zeros(n)


class AgaPfMoves(MoveKernel):
    """`agapf.variant: mcmc`: selection as resampling at every point, then crossover and mutation as MH moves
    tried with the adaptive probabilities."""

    name = "agapf"

    every_point = True  # selection

    def sweep(self, f, target, z):
        g, rng = f.cfg.agapf, f.rng
        fit = np.exp(target - target.max())
        total = fit.sum()
        f_avg, f_max = float(fit.mean() / total), float(fit.max() / total)
        top = float(target.max())

        def fitness(t):
            return np.exp(t - top) / total

        def log_pc(t_a, t_b):
            return np.log(adaptive_pc(np.maximum(fitness(t_a), fitness(t_b)), f_avg, f_max, g.pc1, g.pc2, g.a,
                                      g.curve))

        def log_pm(t):
            return np.log(adaptive_pm(fitness(t), f_avg, f_max, g.pm1, g.pm2, g.a, g.curve))

        x, target, crossed = moves.pair_scale(f.x, target, f.log_target, rng,
                                              lambda m: arithmetic_scale(rng, m), log_attempt=log_pc)
        x, target, mutated = moves.random_walk(x, target, f.log_target, rng, f.chol(RW_SCALE),
                                               log_attempt=log_pm)
        return x, target, crossed + mutated, 2 * f.n


ALGORITHMS = (Algorithm("agapf", "adaptive genetic", "agapf", AgapfConfig, AgaPfFilter, AgaPfMoves),)
