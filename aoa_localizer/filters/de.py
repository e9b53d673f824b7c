"""Differential evolution on a particle population (UPF-DE paper sec. 3.2): mutation with distinct indices,
binomial crossover with one forced dimension, greedy selection by fitness. Vectorised over particles."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aoa_localizer.core.spec import choice, param, variant_choice


@dataclass(frozen=True)
class DeConfig:
    """Differential evolution of UPF-DE and PF-DE: V = F1 X_r1 + F2 (X_r2 - X_r3), binomial crossover Cr, G
    generations."""

    variant: str = variant_choice("UPF-DE/PF-DE")
    fitness: str = choice("posterior", ("posterior", "ratio"), "UPF-DE/PF-DE paper variant: a trial's fitness, "
                          "`posterior` (L p: the path posterior, default) or `ratio` (L p / q, unbounded)")
    f1: float = param(
        1.0, "UPF-DE/PF-DE: scale F1 of the base vector in V = F1 X_r1 + F2 (X_r2 - X_r3)", low=0.0, low_open=True,
        high=10.0
    )
    f2: float = param(0.9, "UPF-DE/PF-DE: scale F2 of the difference vector", low=0.0, low_open=True, high=10.0)
    cr: float = param(0.6, "UPF-DE/PF-DE: binomial crossover rate", low=0.0, high=1.0)
    generations: int = param(20, "UPF-DE/PF-DE: DE generations G per measurement", low=0, high=200)


def distinct_indices(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) indices r1, r2, r3, distinct from each other and from the row i (needs n >= 4)."""
    keys = rng.random((n, n))
    keys[np.arange(n), np.arange(n)] = np.inf
    return np.argsort(keys, axis=1)[:, :3]


def mutate(x: np.ndarray, r: np.ndarray, f1: float, f2: float) -> np.ndarray:
    """V_i = F1 X_r1 + F2 (X_r2 - X_r3) (eq. 9)."""
    return f1 * x[r[:, 0]] + f2 * (x[r[:, 1]] - x[r[:, 2]])


def crossover(x: np.ndarray, v: np.ndarray, cr: float, u: np.ndarray, forced: np.ndarray) -> np.ndarray:
    """U = v where u <= Cr or at the forced dimension, else x (eq. 10); u (n, d) uniform, forced (n,) indices."""
    take = u <= cr
    take[np.arange(x.shape[0]), forced] = True
    return np.where(take, v, x)


def evolve(x: np.ndarray, fitness: np.ndarray, score, cfg, rng: np.random.Generator):
    """G generations of mutation, crossover and greedy selection (keep the trial if its fitness is higher).

    `score(trials)` gives the log-fitness of trial vectors, row i judged as particle i's replacement."""
    n, d = x.shape
    if n < 4:
        return x, fitness
    for _ in range(cfg.generations):
        trial = crossover(x, mutate(x, distinct_indices(n, rng), cfg.f1, cfg.f2), cfg.cr,
                          rng.random((n, d)), np.asarray(rng.integers(0, d, size=n)))
        f = score(trial)
        better = f > fitness
        x = np.where(better[:, None], trial, x)
        fitness = np.where(better, f, fitness)
    return x, fitness
