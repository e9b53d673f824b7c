"""Resampling schemes: each maps normalised weights to N ancestor indices with the filter's own Generator."""
from __future__ import annotations

import numpy as np


def _search(weights: np.ndarray, positions: np.ndarray) -> np.ndarray:
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0  # guard against round-off leaving the last bin short
    return np.searchsorted(cumulative, positions, side="right")


def systematic(weights: np.ndarray, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """One uniform offset, N evenly spaced pointers (the AFSA paper's choice); `n` pointers if given (ESPF draws N
    of its 2N pool)."""
    n = weights.size if n is None else n
    return _search(weights, (np.arange(n) + rng.random()) / n)


def stratified(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniform pointer in each of N equal strata."""
    n = weights.size
    return _search(weights, (np.arange(n) + rng.random(n)) / n)


def multinomial(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """N independent draws from the weights."""
    return _search(weights, rng.random(weights.size))


def residual(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """floor(N w_i) copies of each particle, the rest drawn multinomially from the residual weights."""
    n = weights.size
    copies = np.floor(n * weights).astype(int)
    idx = np.repeat(np.arange(n), copies)
    rest = n - idx.size
    if rest:
        res = n * weights - copies
        idx = np.concatenate([idx, _search(res / res.sum(), rng.random(rest))])
    return idx


SCHEMES = {"systematic": systematic, "stratified": stratified, "multinomial": multinomial, "residual": residual}
