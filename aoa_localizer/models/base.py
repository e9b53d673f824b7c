"""What a filter needs from a model: sample the transition, score a measurement, (optionally) remember it."""
from __future__ import annotations

import numpy as np


class StateSpaceModel:
    """x_k ~ p(x_k | x_{k-1}), z_k ~ p(z_k | x_k), with k counted from 1 at the first measurement."""

    dim: int = 1

    def transition(self, x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
        """Draw x_k for every row of x = x_{k-1} (shape (N, dim))."""
        raise NotImplementedError

    def loglik(self, x: np.ndarray, z, k: int) -> np.ndarray:
        """log p(z | x) for every row of x (any leading shape)."""
        raise NotImplementedError

    def usable(self, z) -> bool:
        """Whether z can be used at all (finite); an unusable one is skipped by the filter."""
        return bool(np.all(np.isfinite(np.asarray(z, float))))

    def observe(self, z):
        """Remember z (models whose move steps need the past); nothing by default."""
