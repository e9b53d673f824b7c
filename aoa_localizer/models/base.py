"""The model contract. Every model gives what the particle-filter skeleton calls (StateSpaceModel); what only some
filters need is an optional capability, a typed protocol that `make_filter` checks before a filter runs."""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

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


@runtime_checkable
class StaticPosterior(Protocol):
    """A static state whose whole posterior over the kept measurements can be evaluated: what MCMC moves, the
    fish school of AFSA and the robustness layer need. `history` holds the kept measurements."""

    history: Any

    def set_prior(self, mean, cov) -> None: ...

    def log_posterior(self, x: np.ndarray) -> np.ndarray: ...


@runtime_checkable
class LatentNoise(Protocol):
    """A StaticPosterior that is a marginal over discrete noise hypotheses h: its joint with h can be evaluated per
    hypothesis and given one, so moves can be made on place and hypothesis together (a Gibbs draw of h, then moves
    of x given it) at the cost of one hypothesis per look instead of all."""

    def hypotheses_log_joint(self, x: np.ndarray) -> np.ndarray | None: ...

    def log_posterior_given(self, x: np.ndarray, h: np.ndarray) -> np.ndarray: ...


@runtime_checkable
class TransitionDensity(Protocol):
    """log p(x_k | x_{k-1}) can be evaluated (a proposal other than the transition needs it in its weight)."""

    def transition_logpdf(self, x: np.ndarray, x_prev: np.ndarray, k: int) -> np.ndarray: ...


@runtime_checkable
class UnscentedForm(Protocol):
    """The model as a UKF sees it at step k: (f, Q, h, R, which measurement components are angles, z vector)."""

    def ukf(self, k: int, z) -> tuple: ...


CAPABILITY_WORDS: dict[type, str] = {
    StaticPosterior: "StaticPosterior (history, set_prior, log_posterior: a static state's whole posterior)",
    TransitionDensity: "TransitionDensity (transition_logpdf)",
    UnscentedForm: "UnscentedForm (ukf: the model as a UKF sees it)",
}
