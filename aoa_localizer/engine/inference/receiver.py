"""What is not known about the receiver, as part of the posterior: its noise scale and its wild share.

Until the readings calibrate the noise (noise.py needs about 40 of them), the bearing noise is a latent
parameter: a grid of hypotheses (a scale on every point's sigma, and a point outlier share) with a weakly
informative prior, marginalised jointly with the position. The scale is shared by all points, so the
marginal is a sum over hypotheses of products over points, not a product of per-point mixtures: three
bearings that cross in a 30 deg triangle say "the noise is about 20 deg" and widen the ellipse accordingly,
where a fixed 1.1 deg would call two of them wild and publish a tiny ellipse at one crossing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import TWO_PI
from aoa_localizer.engine.inference.receiver_pool import PooledNoise
from aoa_localizer.engine.points.preprocess import reading_sigma
from aoa_localizer.engine.scheduling.slices import DENSITIES, metered

SIGMA_SPAN_DEG = (0.5, 45.0)  # the bearing sigmas the prior covers
_N_SCALES = 8  # a factor 1.9 apart: the marginal over the sigma is smooth, and each hypothesis costs a pass
# log-normal around the configured sigma, wide enough that the span's far end is within two standard deviations
_CENTRE_LOG_SD = 0.5 * math.log(SIGMA_SPAN_DEG[1] / SIGMA_SPAN_DEG[0])
_OUTLIERS = (0.02, 0.15, 0.5)  # point outlier shares (up to a ghost as strong as the emitter) ...
_OUTLIER_PRIOR = (0.45, 0.4, 0.15)  # ... and their prior weights


@dataclass(frozen=True)
class NoiseGrid:
    """Hypotheses about the receiver's noise: a scale on each point's sigma and a point outlier share, with their
    prior log weights (normalised)."""

    scale: np.ndarray
    outlier: np.ndarray
    log_prior: np.ndarray
    distinct: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        # The densities are summed as they are, not as logs (_terms): a wild share keeps each mixture off zero.
        if not np.all((self.outlier > 0.0) & (self.outlier < 1.0)):
            raise ValueError(f"the noise hypotheses' wild shares must be in (0, 1), not {self.outlier}")
        # the distinct scales and each hypothesis' one (every likelihood under the latent noise reads them)
        object.__setattr__(self, "distinct", np.unique(self.scale, return_inverse=True))

    @classmethod
    def weak(cls, configured_sigma_deg: float, pooled: PooledNoise | None = None) -> NoiseGrid:
        """The weakly informative prior: sigmas over SIGMA_SPAN_DEG (log-spaced), log-normal around the configured
        sigma (wide: the whole span is plausible); each with every wild share. `pooled`: the receiver's other
        channels' calibration (receiver_pool.py), around which the prior is centred instead, as narrow as their
        spread allows. The hypotheses' scales stay on the configured sigma, which the points are made with."""
        sig = np.geomspace(*SIGMA_SPAN_DEG, _N_SCALES)
        log_s = np.log(sig / configured_sigma_deg)
        centre, log_sd = (0.0, _CENTRE_LOG_SD) if pooled is None else (math.log(pooled.scale), pooled.log_sd)
        w_scale = np.exp(-0.5 * ((log_s - centre) / log_sd) ** 2)
        w = np.outer(w_scale, _OUTLIER_PRIOR).ravel()
        scale = np.repeat(np.exp(log_s), len(_OUTLIERS))
        outlier = np.tile(np.array(_OUTLIERS), _N_SCALES)
        return cls(scale, outlier, np.log(w / w.sum()))

    def coarse(self) -> NoiseGrid:
        """Every other sigma with the middle wild share, each holding its neighbours' prior mass: a sixth of the
        hypotheses, for scoring a grid of places whose bearings are already widened by the cells' size."""
        sigmas = np.unique(self.scale)
        keep = sigmas[1::2]
        mid = _OUTLIERS[len(_OUTLIERS) // 2]
        nearest = np.abs(np.log(self.scale)[:, None] - np.log(keep)[None, :]).argmin(axis=1)
        mass = np.bincount(nearest, weights=np.exp(self.log_prior), minlength=keep.size)
        return NoiseGrid(keep, np.full(keep.size, mid), np.log(mass / mass.sum()))

    @classmethod
    def for_config(cls, cfg: LocalizerConfig, pooled: PooledNoise | None = None) -> NoiseGrid:
        """weak() on the configured sigma: `bearing_sigma_deg`, or the geometric middle of sigma(Q)."""
        if cfg.sigma_model == "constant":
            return cls.weak(cfg.bearing_sigma_deg, pooled)
        return cls.weak(math.degrees(math.sqrt(reading_sigma(40.0, cfg) * reading_sigma(100.0, cfg))), pooled)




def log_densities(resid, var, extra_var, grid: NoiseGrid) -> np.ndarray:
    """sum_k log p(resid_k | h) per hypothesis, (..., H), for resid, var (points' sigma^2) and extra_var (antenna
    position and smoothing terms, not scaled) broadcast to (..., K): the part of the marginal that adds up over
    points, so a running sum takes a new point at the cost of that point alone."""
    gauss, _ = _gauss(resid, var, extra_var, grid)
    mix = gauss[grid.distinct[1]]  # (H, ..., K), made in place from here: the arrays are particles x points x H
    mix *= (1.0 - grid.outlier).reshape((-1,) + (1,) * (mix.ndim - 1))
    mix += (grid.outlier / TWO_PI).reshape((-1,) + (1,) * (mix.ndim - 1))
    return np.moveaxis(np.log(mix, out=mix).sum(axis=-1), 0, -1)


@metered(DENSITIES, lambda resid, var, extra_var, grid, h: math.prod(np.broadcast_shapes((np.size(h), 1), np.shape(var),
                                                                          np.shape(extra_var))))
def given_log_densities(resid, var, extra_var, grid: NoiseGrid, h: np.ndarray) -> np.ndarray:
    """log_densities' column h[i] for each row i of resid (M, K): the points' log densities given one hypothesis per
    row, each made by the same operations (so the same numbers), at the cost of one hypothesis instead of all."""
    resid2 = np.square(resid)
    v = np.square(grid.scale[h])[:, None] * var + extra_var
    mix = np.exp(-0.5 * resid2 / v) / np.sqrt(TWO_PI * v)
    mix *= (1.0 - grid.outlier[h])[:, None]
    mix += (grid.outlier[h] / TWO_PI)[:, None]
    return np.log(mix, out=mix).sum(axis=-1)


def log_sum(densities: np.ndarray, grid: NoiseGrid) -> np.ndarray:
    """The marginal log sum_h prior_h prod_k p(resid_k | h) from log_densities' per-hypothesis sums (..., H)."""
    return _joint(densities, grid)[0]


def em_weights(resid, var, extra_var, grid: NoiseGrid):
    """The marginal's EM quantities at each place: (log marginal (...), precision weight (..., K) = E[inlier /
    variance], inlier weight (..., K)), the expectations over the hypotheses' posterior at that place."""
    mix, inl, v = _terms(resid, var, extra_var, grid)
    total, per_h = _joint(_per_hypothesis(mix), grid)
    post = np.exp(per_h - total[..., None])  # (..., H)
    gamma = inl / mix * np.moveaxis(post, -1, 0)[..., None]
    return total, np.sum(gamma / v, axis=0), np.sum(gamma, axis=0)


def _terms(resid, var, extra_var, grid: NoiseGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's mixture density, its inlier part (for the EM weights) and its variance, per hypothesis along
    a first axis in the grid's order: (H, ..., K) each. Densities, not their logs: the wild share keeps every
    mixture above share / 2 pi, and one exp per scale with a log per hypothesis costs less than a log-sum-exp per
    hypothesis. The Gaussian is made once per scale and shared by that scale's wild shares; every hypothesis in
    one array operation, since at a few points numpy's per-call cost is most of the work."""
    gauss, v = _gauss(resid, var, extra_var, grid)
    which = grid.distinct[1]
    outlier = grid.outlier.reshape((-1,) + (1,) * (gauss.ndim - 1))
    inl = (1.0 - outlier) * gauss[which]
    return inl + outlier / TWO_PI, inl, v[which]


# what the callers make: a mixture per hypothesis
@metered(DENSITIES, lambda resid, var, extra_var, grid: grid.scale.size * math.prod(
    np.broadcast_shapes(np.shape(resid), np.shape(var), np.shape(extra_var))))
def _gauss(resid, var, extra_var, grid: NoiseGrid) -> tuple[np.ndarray, np.ndarray]:
    """Each point's Gaussian density and variance under each distinct scale of the grid: (scales, ..., K) each."""
    resid2 = np.square(resid)
    shape = np.broadcast_shapes(np.shape(resid2), np.shape(var), np.shape(extra_var))
    v = np.square(grid.distinct[0]).reshape((-1,) + (1,) * len(shape)) * var + extra_var
    return np.exp(-0.5 * resid2 / v) / np.sqrt(TWO_PI * v), v


def _per_hypothesis(mix: np.ndarray) -> np.ndarray:
    """sum_k log mix over the points, hypotheses last: (H, ..., K) -> (..., H)."""
    return np.moveaxis(np.log(mix).sum(axis=-1), 0, -1)


def _joint(densities: np.ndarray, grid: NoiseGrid):
    """(log marginal (...), per-hypothesis log joint (..., H)) from the per-hypothesis log densities (..., H)."""
    per_h = densities + grid.log_prior
    top = np.max(per_h, axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    return np.log(np.sum(np.exp(per_h - top), axis=-1)) + top[..., 0], per_h
