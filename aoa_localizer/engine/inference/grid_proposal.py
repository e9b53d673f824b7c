"""An importance proposal from a polar grid's coarse posterior score: a cell drawn in proportion to its score times
its area, then a place uniform in the cell's azimuth and log range.

Before a bearing-only posterior is determined its mass lies along rays, from the antennas out to kilometres; a
Gaussian (or Student-t) at a mode's Laplace covariance reaches only the ray's near end, and an importance sample
from it keeps a few heavy draws and an ellipse far too small. The start search's grid already scores the ray's
whole length (log-spaced in range, each bearing widened by its cell), so drawing from it reaches the tail.
"""
from __future__ import annotations

import math

import numpy as np

from aoa_localizer.engine.geodesy import TWO_PI
from aoa_localizer.engine.inference.safety import Proposal


class GridProposal:
    """q(x) over a polar grid at `centre` with cell centres at log ranges `log_r` (R,, evenly spaced) and azimuths
    (i + 1/2) 2 pi / A, from the grid's log score (A, R); zero outside the grid's ranges."""

    def __init__(self, centre: np.ndarray, log_r: np.ndarray, score: np.ndarray):
        self.centre = np.asarray(centre, float)
        self.log_r = np.asarray(log_r, float)
        self.n_az = score.shape[0]
        self.d_az, self.d_log = TWO_PI / self.n_az, float(self.log_r[1] - self.log_r[0])
        # a cell's mass: its density times its area, r^2 d_az d_log r
        log_mass = np.where(np.isfinite(score), score + 2.0 * self.log_r[None, :], -np.inf)
        top = float(np.max(log_mass))
        p = np.exp(log_mass - top).ravel()
        self.p = p / p.sum()
        self.log_p = np.log(np.maximum(self.p, 1e-300)).reshape(score.shape)

    @classmethod
    def usable(cls, centre: np.ndarray, log_r: np.ndarray, score: np.ndarray) -> GridProposal | None:
        """The proposal, or None for a grid with no finite score (nothing to draw from)."""
        if score.ndim != 2 or score.shape[1] != log_r.size or log_r.size < 2 or not np.isfinite(score).any():
            return None
        return cls(centre, log_r, score)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        cell = rng.choice(self.p.size, size=n, p=self.p)
        a, r = np.unravel_index(cell, self.log_p.shape)
        az = (a + rng.random(n)) * self.d_az
        rho = np.exp(self.log_r[r] + (rng.random(n) - 0.5) * self.d_log)
        return self.centre + rho[:, None] * np.stack([np.cos(az), np.sin(az)], axis=-1)

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """log q at places x (..., 2): the cell's probability over its area in (azimuth, log range), times the
        Jacobian 1 / r^2 of that polar map; -inf outside the grid's ranges."""
        d = np.asarray(x, float) - self.centre
        rho2 = np.maximum(d[..., 0] ** 2 + d[..., 1] ** 2, 1e-300)
        log_rho = 0.5 * np.log(rho2)
        r = np.rint((log_rho - self.log_r[0]) / self.d_log).astype(int)
        inside = (r >= 0) & (r < self.log_r.size)
        a = np.floor(np.arctan2(d[..., 1], d[..., 0]) % TWO_PI / self.d_az).astype(int) % self.n_az
        out = self.log_p[a, np.clip(r, 0, self.log_r.size - 1)] - math.log(self.d_az * self.d_log) - 2.0 * log_rho
        return np.where(inside, out, -np.inf)


class Blend:
    """A mixture of proposals with fixed weights: draws from each in its share, the density of the mixture."""

    def __init__(self, parts: list[Proposal], weights: list[float]):
        self.parts = parts
        w = np.asarray(weights, float)
        self.log_w = np.log(w / w.sum())

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        comp = rng.choice(len(self.parts), size=n, p=np.exp(self.log_w))
        out = np.empty((n, 2))
        for c, part in enumerate(self.parts):
            sel = comp == c
            out[sel] = part.sample(int(sel.sum()), rng)
        return out

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        return np.logaddexp.reduce(np.stack([lw + p.logpdf(x) for lw, p in zip(self.log_w, self.parts, strict=True)]),
                                   axis=0)
