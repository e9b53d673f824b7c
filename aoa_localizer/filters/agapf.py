"""AGA-PF: the non-degenerate particle filter with an adaptive genetic algorithm (Wu Hao, Sun Xiaoyan 2016).

Each step: propagate, weight w = L(z|x), fitness = normalised weight (eq. 17); roulette selection by
fitness; arithmetic crossover of pairs with the adaptive probability pc of eq. 18 (f' the fitter parent);
Gaussian mutation with the adaptive probability pm of eq. 19 (f the individual's own fitness); no other
resampling. The offspring are weighted by their likelihood for the estimate; the next step starts
from equal weights.

Readings: eq. 19 as printed (pm2 + (pm1 - pm2)/(1 + exp(-A ...))) rises towards pm1 for the fittest,
against the text's stated intent (good individuals mutate less); we implement the intent, the same
curve mirrored: pm2 + (pm1 - pm2)/(1 + exp(+A ...)), which falls to pm2 at f_max. The real-valued
operators are ours: crossover children a x1 + (1-a) x2 and (1-a) x1 + a x2 with a ~ U(0, 1);
mutation adds N(0, s^2) with s the population's standard deviation per dimension.
"""
from __future__ import annotations

import numpy as np

from aoa_localizer.filters.base import ParticleFilter, ReplacesResampling


def adaptive_pc(f_parent, f_avg: float, f_max: float, pc1: float, pc2: float, a: float):
    """Eq. 18: pc1 below the average fitness; above it falls from (pc1+pc2)/2 towards pc2 at f_max."""
    f = np.asarray(f_parent, float)
    span = max(f_max - f_avg, 1e-300)
    with np.errstate(over="ignore"):
        above = pc1 - (pc1 - pc2) / (1 + np.exp(-a * 2 * (f - f_avg) / span))
    return np.where(f >= f_avg, above, pc1)


def adaptive_pm(f, f_avg: float, f_max: float, pm1: float, pm2: float, a: float):
    """Eq. 19 as intended: pm1 below the average; above it falls from (pm1+pm2)/2 towards pm2 at f_max."""
    f = np.asarray(f, float)
    span = max(f_max - f_avg, 1e-300)
    with np.errstate(over="ignore"):
        above = pm2 + (pm1 - pm2) / (1 + np.exp(a * 2 * (f - f_avg) / span))
    return np.where(f >= f_avg, above, pm1)


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
        cross = rng.random(i.size) < adaptive_pc(np.maximum(pf[i], pf[j]), f_avg, f_max, g.pc1, g.pc2, g.a)
        a = rng.random(i.size)[:, None]
        xi, xj = x[i], x[j]
        x[i] = np.where(cross[:, None], a * xi + (1 - a) * xj, xi)
        x[j] = np.where(cross[:, None], (1 - a) * xi + a * xj, xj)
        mutate = rng.random(n) < adaptive_pm(pf, f_avg, f_max, g.pm1, g.pm2, g.a)
        spread = np.std(self.x, axis=0)
        x = np.where(mutate[:, None], x + spread * rng.standard_normal(x.shape), x)
        ll = self.loglik(x, z)
        if np.isfinite(ll.max()):
            self.x, self.last_ll = x, ll
            self.logw = ll - ll.max()
