"""Global-mode safety for the emitter posterior: notice a cloud that no longer explains the data, and moves
that can cross kilometres of low posterior while leaving p(x | all kept points) invariant.

* `HealthMonitor`: the share of recent points the cloud explains only as outliers, tested against the
  calibrated outlier rate (a binomial tail), so 30 % multipath is normal and 8 wild points in 10 are not.
* `ModeProposal`: a Student-t mixture over the modes the global search found (each at its Laplace
  covariance, widened) plus a broad defensive component. Its density is exact, so an independence
  Metropolis-Hastings move from it has the correct Hastings ratio, and importance sampling from it gives
  a weighted sample of the posterior (the start, and a restart from a far better global hypothesis).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np
from scipy.special import gammaln

from aoa_localizer.engine.distributions import binom_sf
from aoa_localizer.engine.inference.global_search import Mode, Points
from aoa_localizer.filters import moves
from aoa_localizer.filters.moves import Proposal
from aoa_localizer.filters.resampling import systematic

_T_DOF = 3.0  # heavy tails: the ratio posterior / proposal stays bounded in the mode's tails
_WIDEN = 1.5  # the Laplace covariance underestimates a bearing posterior's banana tails
_DEFENSIVE = 0.1  # share of the broad component
_MIN_COMPONENT = 0.02  # every kept mode is proposed at least this often
_KEEP_LOG_MASS = 30.0  # modes more than this many nats below the best are not proposed
_MAX_DRAWS = 2000  # an importance sample's draws (a look each) beyond 8 a particle of the default N = 100
_BROAD_MIN_SIGMA_M = 100.0  # the mode proposal's broad component is at least this wide


class HealthMonitor:
    """Recent points' outlier flags; `alarm` when their count is implausible under the outlier rate."""

    def __init__(self, window: int, p_value: float):
        self.flags: deque[bool] = deque(maxlen=window)
        self.window, self.p_value = window, p_value
        self.alarm_since: int | None = None  # index of the first flagged point of the current alarm
        self._thresholds: dict[float, int] = {}

    def threshold(self, outlier_prob: float) -> int:
        """Smallest count of flagged points in a full window with a binomial tail below p_value (cached: the
        outlier rate changes only when the noise is calibrated)."""
        if outlier_prob not in self._thresholds:
            self._thresholds[outlier_prob] = self._threshold(outlier_prob)
        return self._thresholds[outlier_prob]

    def _threshold(self, outlier_prob: float) -> int:
        k = np.arange(self.window + 1)
        tail = binom_sf(k - 1, self.window, min(outlier_prob, 0.99))
        return int(max(3, k[np.argmax(tail < self.p_value)] if (tail < self.p_value).any() else self.window + 1))

    def push(self, flagged: bool, index: int, outlier_prob: float) -> bool:
        """Add the newest point's flag (point number `index`); returns whether the cloud is in alarm."""
        self.flags.append(bool(flagged))
        if sum(self.flags) >= self.threshold(outlier_prob):
            if self.alarm_since is None:
                first = next(i for i, f in enumerate(self.flags) if f)
                self.alarm_since = index - (len(self.flags) - 1 - first)
        elif not flagged:
            self.alarm_since = None
        return self.alarm_since is not None

    def clear(self):
        self.flags.clear()
        self.alarm_since = None

    @property
    def share(self) -> float:
        return sum(self.flags) / len(self.flags) if self.flags else 0.0


def _t_logpdf(x: np.ndarray, mean: np.ndarray, chol: np.ndarray, logdet: float) -> np.ndarray:
    d = moves.whiten(x - mean, chol)
    m2 = np.sum(d * d, axis=-1)
    nu = _T_DOF
    return (gammaln((nu + 2) / 2) - gammaln(nu / 2) - math.log(nu * math.pi) - 0.5 * logdet
            - (nu + 2) / 2 * np.log1p(m2 / nu))


class ModeProposal:
    """Independence proposal q(x): a mixture of bivariate Student-t laws at the modes, plus a broad one."""

    def __init__(self, modes: list[Mode], broad_sigma_m: float):
        best = modes[0].log_mass
        kept = [m for m in modes if m.log_mass > best - _KEEP_LOG_MASS]
        mass = np.exp(np.array([m.log_mass for m in kept]) - best)
        mass = np.maximum(mass / mass.sum(), _MIN_COMPONENT)
        self.weights = np.append((1 - _DEFENSIVE) * mass / mass.sum(), _DEFENSIVE)
        self.means = [m.mean for m in kept] + [kept[0].mean]
        covs = [_WIDEN**2 * m.cov for m in kept] + [broad_sigma_m**2 * np.eye(2)]
        self.chols = [np.linalg.cholesky(c + 1e-9 * np.eye(2)) for c in covs]
        self.logdets = [2 * float(np.sum(np.log(np.diag(c)))) for c in self.chols]

    @classmethod
    def over(cls, modes: list[Mode], pts: Points) -> ModeProposal:
        """The proposal for the posterior over `pts`: its broad component as wide as the farthest point from the
        best mode (at least _BROAD_MIN_SIGMA_M)."""
        centre = modes[0].mean
        far = float(np.max(np.hypot(pts.east - centre[0], pts.north - centre[1])))
        return cls(modes, max(_BROAD_MIN_SIGMA_M, far))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        comp = rng.choice(len(self.weights), size=n, p=self.weights)
        z = rng.standard_normal((n, 2)) / np.sqrt(rng.chisquare(_T_DOF, size=n) / _T_DOF)[:, None]
        out = np.empty((n, 2))
        for c in range(len(self.weights)):
            sel = comp == c
            out[sel] = self.means[c] + z[sel] @ self.chols[c].T
        return out

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        parts = np.stack([math.log(w) + _t_logpdf(x, m, c, ld)
                          for w, m, c, ld in zip(self.weights, self.means, self.chols, self.logdets, strict=False)])
        return np.logaddexp.reduce(parts, axis=0)


def weighted_sample(log_target, proposal: Proposal, n: int, rng: np.random.Generator
                    ) -> tuple[np.ndarray, np.ndarray]:
    """n draws from q and their log weights pi / q (unnormalised; -inf where pi is not finite): a weighted sample of
    the posterior."""
    y = proposal.sample(n, rng)
    return y, log_weights(log_target, proposal, y)


def log_weights(log_target, proposal: Proposal, y: np.ndarray) -> np.ndarray:
    """The log importance weights pi / q of draws y from q (unnormalised; -inf where pi is not finite)."""
    lw = log_target(y) - proposal.logpdf(y)
    return np.where(np.isfinite(lw), lw, -np.inf)


def importance_sample(log_target, proposal: Proposal, n: int, rng: np.random.Generator, draws_per_particle=8):
    """N particles drawn from q and resampled by pi / q (systematic): a sample of the posterior, modes in
    proportion to their mass. Duplicates are left for the MH sweeps that follow to spread. `draws_per_particle`
    draws a particle, at most _MAX_DRAWS in all: a large cloud's diversity comes from its sweeps."""
    y, lw = weighted_sample(log_target, proposal, min(draws_per_particle * n, max(n, _MAX_DRAWS)), rng)
    w = np.exp(lw - lw.max())
    return y[systematic(w / w.sum(), rng)[:n]] if w.sum() > 0 else y[:n]
