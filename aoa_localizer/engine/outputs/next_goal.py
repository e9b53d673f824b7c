"""Where to drive next (the node's `emitter/next_goal`): the place near the vehicle whose next bearing is expected to
shrink the posterior most.

The criterion is the expected information gain of one bearing taken there, the mutual information between that
bearing and the emitter's place under the particle cloud (docs/design.md, "Where to drive next", argues it against
the D-optimal criterion). With a bearing theta_i = the direction from the candidate to particle i and Gaussian
bearing noise sigma, the bearing's predictive law is a mixture of equal-width Gaussians; its information is bounded
below in closed form by the Bhattacharyya bound of Kolchinsky and Tracey (2017):

    I >= -sum_i w_i log sum_j w_j exp(-(theta_i - theta_j)^2 / (8 sigma^2))

which is 0 when every particle lies in one direction and log(1 / sum w^2) when no two can be confused. It needs no
random draws, so a goal is reproducible. Candidates are the vehicle's place and RINGS x AZIMUTHS places around it
out to the goal radius; among those within NEAR_BEST of the best gain, the nearest to the vehicle wins (near the
emitter the bound saturates, and a shorter drive that learns as much is the better goal).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.geodesy import wrap_pi

RINGS = (0.25, 0.5, 0.75, 1.0)  # candidate rings, in goal radii
AZIMUTHS = 16  # candidates per ring
MAX_PARTICLES = 128  # the gain costs candidates x particles^2: a larger cloud is thinned evenly
NEAR_BEST = 0.97  # candidates within this share of the best gain count as equally good


@dataclass(frozen=True)
class NextGoal:
    """A goal in the map frame (east, north, m), its expected information (nats) and the information of a bearing
    taken where the vehicle is now."""

    east: float
    north: float
    gain_nats: float
    here_nats: float


def candidates(east: float, north: float, radius_m: float) -> np.ndarray:
    """(C, 2) places: the vehicle's, then each ring's AZIMUTHS places (from east, anticlockwise)."""
    angles = 2.0 * math.pi * np.arange(AZIMUTHS) / AZIMUTHS
    rings = np.asarray(RINGS)[:, None] * radius_m
    ring_places = np.stack([east + rings * np.cos(angles), north + rings * np.sin(angles)], axis=-1).reshape(-1, 2)
    return np.vstack([[east, north], ring_places])


def thinned(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """At most MAX_PARTICLES particles: every k-th, with its weight (renormalised)."""
    step = max(1, math.ceil(len(x) / MAX_PARTICLES))
    x, w = x[::step], w[::step]
    return x, w / w.sum()


def bearing_information(places: np.ndarray, x: np.ndarray, w: np.ndarray, sigma_rad: float) -> np.ndarray:
    """(C,) the lower bound on the information (nats) a bearing of noise `sigma_rad` from each of `places` gives about
    the emitter, whose posterior is the weighted cloud (x, w) (the module's formula)."""
    theta = np.arctan2(x[None, :, 1] - places[:, None, 1], x[None, :, 0] - places[:, None, 0])  # (C, M)
    d = wrap_pi(theta[:, :, None] - theta[:, None, :])  # (C, M, M)
    overlap = np.exp(-(d**2) / (8.0 * sigma_rad**2)) @ w  # (C, M): sum_j w_j exp(...)
    return -(np.log(overlap) @ w)


def next_goal(x: np.ndarray, w: np.ndarray, vehicle: tuple[float, float], radius_m: float,
              sigma_rad: float) -> NextGoal:
    """The goal within `radius_m` of `vehicle` (east, north) for the posterior cloud (x, w) and a bearing noise of
    `sigma_rad` (see the module's docstring)."""
    places = candidates(vehicle[0], vehicle[1], radius_m)
    xs, ws = thinned(np.asarray(x, float), np.asarray(w, float))
    gain = bearing_information(places, xs, ws, max(sigma_rad, 1e-6))
    best = float(np.max(gain))
    good = np.flatnonzero(gain >= NEAR_BEST * best)
    distance = np.hypot(places[good, 0] - vehicle[0], places[good, 1] - vehicle[1])
    k = int(good[np.argmin(distance)])
    return NextGoal(float(places[k, 0]), float(places[k, 1]), float(gain[k]), float(gain[0]))
