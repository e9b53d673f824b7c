"""AFSA-PF: the artificial-fish-school particle filter (AFSA paper sec. 2.2-2.3), in two variants.

* `paper`: as printed. After weighting, the school swims for up to `max_iterations` rounds on the
  newest bearing's likelihood (swarm towards the neighbours' centre when it is better and not
  crowded, else prey: up to `try_number` random looks within the visual range, step towards the
  first better one, or a random step). Then re-weight, resample every step. `visual`, `step` in metres.
* `mcmc` (default): the paper's school pulls every fish towards the newest bearing line and the
  weights never learn of it, so the cloud shrinks below the real error (over-confident ellipses).
  Here the school moves only after resampling, and each fish's prey look is accepted by the
  Metropolis-Hastings ratio on the whole posterior (all kept bearings and the prior), not by the
  greedy comparison on the newest bearing: the cloud stays a sample of the posterior. The visual
  range is measured in standard deviations of the school (so it means the same at 5 km and at 5 m);
  `max_iterations` is the number of sweeps. The emitter is modelled static, as the paper says it is:
  the random walk u of eq. 17 would make the filter forget old bearings, and the moves already keep
  the school diverse, so `process_noise_m` applies to the paper variant and SIR only. Swarming towards the
  neighbours' centre is not reversible and is left to the paper variant. See docs/design.md for the
  measurements behind the choice.
"""

from __future__ import annotations

import math

import numpy as np

from aoa_localizer.engine.types import ObservationPoint
from aoa_localizer.filters.base import ParticleFilter
from aoa_localizer.models.base import StaticPosterior

# Added to the school's covariance before its Cholesky factor, m^2: keeps moves alive in a collapsed school.
_MIN_SPREAD_M2 = 1e-2


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
    """Fish = particle; the objective is the bearing likelihood (eq. 12)."""

    name = "afsa"
    needs = (StaticPosterior,)

    def __init__(self, settings, rng, model):
        super().__init__(settings, rng, model)
        self.paper = settings.afsa.variant == "paper"
        self.acceptance = float("nan")  # share of accepted moves in the last mcmc move stage
        self.school_rounds = 0  # rounds the paper school swam at the last step
        self.spread = np.eye(2)  # weighted covariance of the school just before the last resampling
        # Log posterior of each fish over the kept history, kept up to date between moves (mcmc only);
        # valid while it counts the same points as the history window.
        self.target = np.zeros(self.n)
        self.target_points = -1

    def predict(self):
        """Paper: the random walk of eq. 17. mcmc: the emitter is static (paper sec. 3.1); the moves keep diversity."""
        if self.paper:
            super().predict()

    # -- the paper's school ---------------------------------------------------------------------
    def initialise(self, particles, prior_mean=None, prior_cov=None):
        super().initialise(particles, prior_mean, prior_cov)
        self.target, self.target_points = self.log_target(self.x), self.posterior_model.history.appended

    def invalidate(self):
        self.target_points = -1

    def targets_known(self, target: np.ndarray):
        self.target, self.target_points = target, self.posterior_model.history.appended

    def after_weight(self, p: ObservationPoint):
        if not self.paper:
            # The fish did not move since the last point: their posterior gains this point's likelihood.
            history = self.posterior_model.history
            fresh = self.target_points == history.appended - 1 and history.dropped == 0
            if fresh:
                self.target = self.target + self.last_ll
                self.target_points += 1
        if self.paper:
            self.x = self.swim(self.x, p)
            ll = self.loglik(self.x, p)
            new = self.prev_logw + ll
            self.logw = new - new.max()

    def should_resample(self) -> bool:
        return True if self.paper else super().should_resample()

    def swim(self, x: np.ndarray, p: ObservationPoint) -> np.ndarray:
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

    # -- the consistent school ------------------------------------------------------------------
    def after_resample(self, p: ObservationPoint):
        if not self.paper:
            self.move()

    def resample(self) -> np.ndarray:
        # The weighted cloud before resampling is the better picture of the posterior's spread:
        # after it a degenerate school may sit on a handful of points.
        self.spread = self.estimate()[1]
        idx = super().resample()
        self.target = self.target[idx]
        return idx

    def move(self):
        """Prey looks accepted by Metropolis-Hastings on the posterior, `max_iterations` sweeps."""
        a, rng, n = self.cfg.afsa, self.rng, self.n
        chol = np.linalg.cholesky(self.spread + _MIN_SPREAD_M2 * np.eye(2))
        if self.target_points != self.posterior_model.history.appended or self.posterior_model.history.dropped:
            self.target = self.log_target(self.x)
        self.target_points = self.posterior_model.history.appended
        target = self.target
        accepted = 0
        for _ in range(a.max_iterations):
            look = self.x + a.visual * uniform_disc(rng, (n,)) @ chol.T
            look_target = self.log_target(look)
            take = np.log(rng.random(n)) < look_target - target
            self.x = np.where(take[:, None], look, self.x)
            target = np.where(take, look_target, target)
            accepted += int(take.sum())
        self.target = target
        self.acceptance = accepted / (n * a.max_iterations)
