"""A receiver's common bias, learned over the emitters it heard: for each emitter, from the others only.

A receiver heard over BIAS_MIN_EMITTERS or more emitters has a bias the crossings can show: the median of its
stations' residuals at the other emitters' estimates, with the variance of that median. Learning each emitter's
from the others keeps any bearing from being counted twice (once in the bias, once in its own fix). The part of
a common bias that only moves every crossing alike cannot be seen this way, and is not claimed.
"""
from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.pooled.grid import Geometry

BIAS_MIN_EMITTERS = 3  # fewer emitters: a receiver's bias cannot be told from the emitters' places
_MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class Bias:
    """A receiver's bias (rad) and its variance (rad^2): over all its emitters, and for each without it."""

    overall: tuple[float, float]
    without: dict


def residuals(geom: Geometry, point: np.ndarray) -> np.ndarray:
    """Each station's centre minus the bearing from it to `point` (rad)."""
    pred = np.arctan2(point[0] - geom.xy[:, 0], point[1] - geom.xy[:, 1])
    return wrap_pi(geom.centre - pred)


def robust_mean(values: list[float]) -> tuple[float, float]:
    """The median of angles (rad) about their circular mean, and its variance (rad^2)."""
    v = np.asarray(values)
    c = math.atan2(float(np.mean(np.sin(v))), float(np.mean(np.cos(v))))
    dev = wrap_pi(v - c)
    med = float(np.median(dev))
    sigma = _MAD_TO_SIGMA * float(np.median(np.abs(dev - med)))
    return float(wrap_pi(c + med)), (math.pi / 2) * sigma**2 / v.size


def learn_biases(geoms: dict[str, Geometry], points: dict[str, np.ndarray]) -> dict[str, Bias]:
    """The bias of every receiver heard over BIAS_MIN_EMITTERS or more of these emitters (at these points)."""
    rows: dict[str, list[tuple[str, float]]] = defaultdict(list)
    for e, g in geoms.items():
        for r, res in zip(g.receivers, residuals(g, points[e]), strict=True):
            rows[r].append((e, float(res)))
    out = {}
    for r, mine in rows.items():
        emitters = {e for e, _ in mine}
        if len(emitters) >= BIAS_MIN_EMITTERS:
            out[r] = Bias(robust_mean([v for _, v in mine]),
                          {e: robust_mean([v for f, v in mine if f != e]) for e in emitters})
    return out
