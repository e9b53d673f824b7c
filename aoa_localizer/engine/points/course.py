"""Bearings measured from the vehicle's forward axis but configured as azimuths from north (a DF array on a car
whose reference was left at north): they turn with the vehicle, which no constant offset explains, and each turn
looks like the emitter jumping. Turned by the vehicle's course over ground (from the readings' velocity), they
line up again up to a constant, the array's mount, which the learned offset then takes (offset.py). A check adopts
this reading of the bearings when it explains them far better than north with an offset (checks.fit_noise).

A reading taken while the vehicle was slower than MIN_SPEED_MPS has no course of its own: it holds the course
before it (the first moving reading's, before any), with no time limit (a configured vehicle reference holds a
heading for `heading_hold_s`): here the fit over the whole drive decides whether the re-reading stands."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.points.preprocess import Columns, Group, columns
from aoa_localizer.engine.types import Reading

MIN_SPEED_MPS = 1.0


def moved(v_east: np.ndarray, v_north: np.ndarray) -> bool:
    """Whether any reading was taken on the move (a course to turn by)."""
    return bool(np.any(np.hypot(v_east, v_north) >= MIN_SPEED_MPS))


def courses(v_east: np.ndarray, v_north: np.ndarray, held: float = math.nan) -> np.ndarray:
    """Each reading's course over ground (ENU rad), in the readings' order; a slow reading holds the course before
    it (`held` before the first of these readings), else the first moving one's; 0 when none has any."""
    v_east, v_north = np.asarray(v_east, float), np.asarray(v_north, float)
    fast = np.hypot(v_east, v_north) >= MIN_SPEED_MPS
    own = np.arctan2(v_north, v_east)
    if not fast.any():
        return np.full(own.shape, 0.0 if math.isnan(held) else held)
    last = np.maximum.accumulate(np.where(fast, np.arange(fast.size), -1))
    before = held if not math.isnan(held) else float(own[np.argmax(fast)])
    return np.where(last >= 0, own[np.maximum(last, 0)], before)


def group_courses(cols: Sequence[Columns]) -> np.ndarray:
    """The course at each reading of these groups' readings (fields), in turn (courses)."""
    if not cols:
        return np.zeros(0)
    return courses(np.concatenate([c.v_east for c in cols]), np.concatenate([c.v_north for c in cols]))


def turned_group(cols: Columns, turn: np.ndarray) -> Group:
    """A fields-only group (preprocess.Group) of the readings `cols` with their bearings turned by `turn` (rad)."""
    return Group(cols=cols._replace(theta=wrap_pi(cols.theta + turn)))


def turned(readings: Sequence[Reading], held: float) -> tuple[Group, float]:
    """The readings with each bearing turned by the vehicle's course (`held`: the course before them, NaN if
    none), and the course the last of them holds."""
    cols = columns(readings)
    c = courses(cols.v_east, cols.v_north, held)
    return turned_group(cols, c), float(c[-1]) if c.size else held
