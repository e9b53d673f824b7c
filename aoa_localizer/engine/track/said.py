"""What a track says after a point: a standing transmitter's place with its state, or a moving one's, as values the
output side formats into an Estimate without reading the track again (outputs/estimates.py)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.inference.co_channel import Count
from aoa_localizer.engine.inference.motion import Motion
from aoa_localizer.engine.types import EstimateState


def positive_definite(cov) -> bool:
    """Finite and full rank to working precision (a cloud of 2 particles, or all on one line, is not)."""
    (a, _), (b, c) = np.asarray(cov, float).tolist()  # 2x2 symmetric: its eigenvalues in closed form
    if not all(map(math.isfinite, (a, b, c))):
        return False
    high = 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)
    return high > 0 and (a * c - b * b) / high > 1e-9 * high  # the low eigenvalue as det / high


@dataclass(frozen=True)
class Standing:
    """A standing transmitter's estimate as its track has it: the place and covariance (`degenerate`: not positive
    definite, then no modes, state or warnings were made), the posterior's modes, the state with the warnings
    behind it, the cloud (its effective size, particles and weights: copies), the transmitter count with the
    antennas of the points it heard (for its transmitters' ratings), and what the motion watch says (`motion`),
    what the estimate may follow of it (`followed`), whether a sure watch goes unheeded and whether the count explains
    the motion."""

    stamp: float
    mean: np.ndarray
    cov: np.ndarray
    degenerate: bool
    modes: list[tuple[float, float, float]]
    state: EstimateState
    warnings: list[str]
    ess: float
    particles: np.ndarray
    weights: np.ndarray
    bearings_used: int
    points_used: int
    noise: dict | None
    count: Count | None
    antennas: np.ndarray | None
    motion: Motion | None
    followed: Motion | None
    unheeded: bool
    explained: bool


@dataclass(frozen=True)
class Moving:
    """A moving transmitter's estimate as its track's motion watch has it: what the watch says (`motion`: place,
    velocity, their covariances, whether the range is observed) and its moving cloud (copies)."""

    stamp: float
    motion: Motion
    particles: np.ndarray
    weights: np.ndarray
    bearings_used: int
    points_used: int
    noise: dict | None


Said = Standing | Moving
