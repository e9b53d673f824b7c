"""AFSA-PF: the artificial-fish-school particle filter (AFSA paper sec. 2.2-2.3), in two variants.

* `paper`: as printed. After weighting, the school swims for up to `max_iterations` rounds on the
  newest bearing's likelihood (swarm towards the neighbours' centre when it is better and not
  crowded, else prey: up to `try_number` random looks within the visual range, step towards the
  first better one, or a random step). Then re-weight, resample every step. `visual`, `step` in metres.
  The paper takes the swarm's neighbourhood among "the other predicted measurements within the visual
  range", in bearing space; we take it in metres (the same set on one bearing's scale, not across points).
* `mcmc` (default): the same school as moves that keep the posterior of all kept points (the paper's school
  pulls every fish towards the newest bearing and the weights never learn of it: over-confident ellipses).
  After each resampling, `max_iterations` sweeps of: the prey as a multiple-try Metropolis move (`mcmc_tries`
  looks within the visual range, one picked in proportion to the posterior, accepted by the MTM ratio), and
  the swarm as a drift proposal towards the centre of the fish of the other half within the visual range
  (a `step` share of the way, the fish itself excluded; at most 200 of them looked at) with its Hastings ratio
  (moves.py). The visual range is
  in standard deviations of the school, so it means the same at 5 km and at 5 m. The emitter is static, as the
  paper says: no random walk (it would make the filter forget old bearings). The crowd factor has no role in a
  move that keeps the posterior, so only the paper variant uses it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aoa_localizer.core.spec import choice, param
from aoa_localizer.filters import moves
from aoa_localizer.filters.algorithm import Algorithm
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.filters.resample_move import MoveKernel
from aoa_localizer.models.base import StaticPosterior

SWARM_NOISE = 0.5  # the swarm proposal's spread around its drift, in visual ranges
SWARM_PEERS = 200  # fish of the other half a swarm looks at, at most (a random subset: O(N) not O(N^2))


@dataclass(frozen=True)
class AfsaConfig:
    """Fish-school settings (AFSA paper sec. 2.2 and 5). `variant` picks the paper's greedy school or ours."""

    variant: str = choice("mcmc", ("mcmc", "paper"), "`mcmc` (default: the school as moves that keep the "
                          "posterior: prey as multiple-try Metropolis, swarm as a drift proposal) or `paper`: the "
                          "school as printed (docs/design.md)")
    visual: float = param(1.0, "visual range: metres (paper) or standard deviations of the school (mcmc)",
                          low=0.0, low_open=True, high=1e4)
    step: float = param(0.3, "fish step: metres (paper), or the share of the way to the swarm's centre (mcmc)",
                        low=0.0, low_open=True, high=1e4)
    crowd: float = param(0.618, "crowd factor delta, paper variant", low=0.0, low_open=True, high=10.0)
    try_number: int = param(50, "prey tries per fish and round (paper); mcmc uses at most `mcmc_tries`",
                            low=1, high=200)
    mcmc_tries: int = param(5, "prey looks of the multiple-try move per fish and sweep (mcmc)", low=2, high=1000)
    max_iterations: int = param(5, "school rounds (paper) or MCMC sweeps (mcmc)", low=1, high=50)
    tolerance: float = param(1e-3, "stop the paper school when the mean log-objective change is smaller",
                             low=0.0, low_open=True, high=1e6)


def uniform_disc(rng: np.random.Generator, shape) -> np.ndarray:
    """Points uniform in the unit disc, shape (*shape, 2): a symmetric look around a fish."""
    angle = rng.uniform(0.0, 2 * math.pi, size=shape)
    radius = np.sqrt(rng.random(size=shape))
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=-1)


def unit(v: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (zero rows stay zero)."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)


class AfsaFilter(ParticleFilter):
    """`afsa.variant: paper`: fish = particle; the objective is the bearing likelihood (eq. 12)."""

    name = "afsa"
    needs = (StaticPosterior,)

    def __init__(self, settings, rng, model):
        super().__init__(settings, rng, model)
        self.school_rounds = 0  # rounds the school swam at the last step

    def after_weight(self, p):
        self.x = self.swim(self.x, p)
        ll = self.loglik(self.x, p)
        new = self.prev_logw + ll
        self.logw = new - new.max()

    def should_resample(self) -> bool:
        return True

    def swim(self, x: np.ndarray, p) -> np.ndarray:
        """Swarm and prey behaviours (eqs. 8-9, 13-15) for all fish and all tries at once."""
        a = self.cfg.afsa
        rng, n = self.rng, int(x.shape[0])
        y = self.loglik(x, p)
        log_crowd = math.log(a.crowd)
        self.school_rounds = 0
        for _ in range(a.max_iterations):
            self.school_rounds += 1
            # Swarm: the neighbours inside the visual range and their centre.
            d2 = np.sum((x[:, None, :] - x[None, :, :]) ** 2, axis=-1)
            near = (d2 < a.visual**2) & ~np.eye(n, dtype=bool)
            nf = near.sum(axis=1)
            centre = (near @ x) / np.maximum(nf, 1)[:, None]
            yc = self.loglik(centre, p)
            swarm = np.asarray((nf > 0) & (yc - np.log(np.maximum(nf, 1)) > log_crowd + y))
            # Prey: try_number looks within the visual range; the first better one wins.
            looks = x[:, None, :] + a.visual * uniform_disc(rng, (n, a.try_number))
            better = np.asarray(self.loglik(looks, p) > y[:, None])
            found = np.any(better, axis=1, keepdims=True)
            first = looks[np.arange(n), better.argmax(axis=1)]
            random_dir = unit(uniform_disc(rng, (n,)))
            direction = np.where(
                swarm[:, None], unit(centre - x), np.where(found, unit(first - x), random_dir)
            )
            x = x + (rng.random(n) * a.step)[:, None] * direction
            y_new = self.loglik(x, p)
            change = float(np.mean(np.abs(y_new - y)))
            y = y_new
            if change < a.tolerance:
                break
        return x


class AfsaMoves(MoveKernel):
    """`afsa.variant: mcmc`: the fish school as moves on the posterior (prey: multiple-try Metropolis; swarm:
    a drift towards the other half's neighbours' centre, with its Hastings ratio)."""

    name = "afsa"

    def sweeps(self, settings) -> int:
        return settings.afsa.max_iterations

    def sweep(self, f, target, z):
        a, rng, n = f.cfg.afsa, f.rng, f.n
        look = f.chol(a.visual)
        x, target, prey = moves.multiple_try(f.x, target, f.log_target, rng, min(a.mcmc_tries, a.try_number),
                                             look)

        def towards_centre(xs, others, _others_target):
            others = others[:SWARM_PEERS]  # the halves are random, so this is a random subset, fixed for the move
            u, v = moves.whiten(xs, look), moves.whiten(others, look)  # distances in visual ranges
            near = np.sum((u[:, None, :] - v[None, :, :]) ** 2, axis=-1) < 1.0
            count = near.sum(axis=1)
            centre = np.where(count[:, None] > 0, (near @ others) / np.maximum(count, 1)[:, None], xs)
            return xs + a.step * (centre - xs)

        x, target, swarm = moves.drift(x, target, f.log_target, rng, towards_centre, SWARM_NOISE * look)
        return x, target, prey + swarm, 2 * n


ALGORITHMS = (Algorithm("afsa", "AFSA-PF", "afsa", AfsaConfig, AfsaFilter, AfsaMoves),)
