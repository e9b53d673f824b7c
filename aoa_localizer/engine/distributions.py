"""Quantiles and tails of the chi-square, normal and binomial laws from scipy.special: what scipy.stats gives,
without its import (about a second of every program's start; tests/test_distributions.py holds them to it)."""
from __future__ import annotations

import numpy as np
from scipy import special


def chi2_ppf(q, df):
    """The chi-square law's `q` quantile with `df` degrees of freedom."""
    return 2.0 * special.gammaincinv(np.asarray(df, float) / 2.0, q)


def chi2_cdf(x, df):
    """P(X <= x) for X chi-square with `df` degrees of freedom."""
    return special.chdtr(df, np.maximum(x, 0.0))


def chi2_sf(x, df):
    """P(X > x) for X chi-square with `df` degrees of freedom."""
    return special.chdtrc(df, np.maximum(x, 0.0))


def norm_ppf(q):
    """The standard normal law's `q` quantile."""
    return special.ndtri(q)


def norm_sf(x):
    """P(Z > x) for Z standard normal."""
    return special.ndtr(-np.asarray(x, float))


def binom_sf(k, n: int, p: float):
    """P(X > k) for X binomial with `n` trials of probability `p` (1 below k = 0, 0 from k = n)."""
    k = np.asarray(k, float)
    inside = special.betainc(np.clip(k, -1.0, n - 1.0) + 1.0, np.maximum(n - k, 1.0), p)
    return np.where(k < 0, 1.0, np.where(k >= n, 0.0, inside))
