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
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import TWO_PI
from aoa_localizer.engine.preprocess import reading_sigma

_LOG_SQRT_2PI = 0.5 * math.log(TWO_PI)
SIGMA_SPAN_DEG = (0.5, 45.0)  # the bearing sigmas the prior covers
_N_SCALES = 12
# log-normal around the configured sigma, wide enough that the span's far end is within two standard deviations
_CENTRE_LOG_SD = 0.5 * math.log(SIGMA_SPAN_DEG[1] / SIGMA_SPAN_DEG[0])
_OUTLIERS = (0.02, 0.1, 0.3, 0.5)  # point outlier shares (up to a ghost as strong as the emitter) ...
_OUTLIER_PRIOR = (0.4, 0.3, 0.2, 0.1)  # ... and their prior weights


@dataclass(frozen=True)
class NoiseGrid:
    """Hypotheses about the receiver's noise: a scale on each point's sigma and a point outlier share, with their
    prior log weights (normalised)."""

    scale: np.ndarray
    outlier: np.ndarray
    log_prior: np.ndarray

    @classmethod
    def weak(cls, configured_sigma_deg: float) -> NoiseGrid:
        """The weakly informative prior: sigmas over SIGMA_SPAN_DEG (log-spaced), log-normal around the configured
        sigma (wide: the whole span is plausible); three wild shares."""
        sig = np.geomspace(*SIGMA_SPAN_DEG, _N_SCALES)
        log_s = np.log(sig / configured_sigma_deg)
        w_scale = np.exp(-0.5 * (log_s / _CENTRE_LOG_SD) ** 2)
        w = np.outer(w_scale, _OUTLIER_PRIOR).ravel()
        scale = np.repeat(np.exp(log_s), len(_OUTLIERS))
        outlier = np.tile(np.array(_OUTLIERS), _N_SCALES)
        return cls(scale, outlier, np.log(w / w.sum()))

    @classmethod
    def for_config(cls, cfg: LocalizerConfig) -> NoiseGrid:
        """weak() centred on the configured sigma: `bearing_sigma_deg`, or the geometric middle of sigma(Q)."""
        if cfg.sigma_model == "constant":
            return cls.weak(cfg.bearing_sigma_deg)
        return cls.weak(math.degrees(math.sqrt(reading_sigma(40.0, cfg) * reading_sigma(100.0, cfg))))


def _hypothesis_terms(resid2, var, extra_var, scale: float, outlier: float):
    """Per-point log mixture density and its Gaussian part (for the EM weights) under one hypothesis."""
    v = scale * scale * var + extra_var
    g = -0.5 * resid2 / v - 0.5 * np.log(v) - _LOG_SQRT_2PI + math.log1p(-outlier)
    return np.logaddexp(g, math.log(outlier / TWO_PI)), g, v


def marginal(resid, var, extra_var, grid: NoiseGrid) -> np.ndarray:
    """log sum_h prior_h prod_k p(resid_k | h): resid, var (points' sigma^2), extra_var (antenna position and
    smoothing terms, not scaled) broadcast to (..., K); returns (...)."""
    return _joint(_terms(resid, var, extra_var, grid), grid)[0]


def em_weights(resid, var, extra_var, grid: NoiseGrid):
    """The marginal's EM quantities at each place: (log marginal (...), precision weight (..., K) = E[inlier /
    variance], inlier weight (..., K)), the expectations over the hypotheses' posterior at that place."""
    terms = _terms(resid, var, extra_var, grid)
    total, per_h = _joint(terms, grid)
    post = np.exp(per_h - total[..., None])  # (..., H)
    prec = np.zeros(np.shape(terms[0][0]))
    inlier = np.zeros_like(prec)
    for h, (ll, g, v) in enumerate(terms):
        gamma = np.exp(g - ll) * post[..., h:h + 1]
        inlier += gamma
        prec += gamma / v
    return total, prec, inlier


def _terms(resid, var, extra_var, grid: NoiseGrid) -> list:
    """_hypothesis_terms of every hypothesis."""
    resid2 = np.square(resid)
    return [_hypothesis_terms(resid2, var, extra_var, s, e)
            for s, e in zip(grid.scale.tolist(), grid.outlier.tolist(), strict=True)]


def _joint(terms: list, grid: NoiseGrid):
    """(log marginal (...), per-hypothesis log joint (..., H)) from the hypotheses' per-point terms (..., K)."""
    per_h = np.stack([ll.sum(axis=-1) for ll, _, _ in terms], axis=-1) + grid.log_prior
    top = np.max(per_h, axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    return np.log(np.sum(np.exp(per_h - top), axis=-1)) + top[..., 0], per_h
