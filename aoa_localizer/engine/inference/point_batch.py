"""Every observation point of a check remade at once: a noise fit tries several noises and offsets, and each trial
needs all the points under it. make_point's maths (preprocess.py), vectorised over the points; make_point stays the
reference the tests hold this to."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import wrap_pi, wrap_pi_float
from aoa_localizer.engine.inference.global_search import Points
from aoa_localizer.engine.inference.noise import NoiseModel
from aoa_localizer.engine.points.course import group_courses, turned_group
from aoa_localizer.engine.points.preprocess import (
    SMALL_POINT,
    TIE_RAD,
    Columns,
    Group,
    columns,
    fields,
    make_point,
)
from aoa_localizer.engine.scheduling.slices import BATCH_MADE, POINTS_MADE, metered
from aoa_localizer.engine.types import ObservationPoint, Reading

Built = tuple[ObservationPoint, np.ndarray]  # a point and the mask of the readings it kept


def rows_of(points: Sequence[ObservationPoint]) -> np.ndarray:
    """(K, 5) rows east, north, theta, sigma, gps sigma of the points."""
    return np.array([[p.east, p.north, p.theta, p.sigma, p.gps_sigma] for p in points])


def points_of(points: Sequence[ObservationPoint]) -> Points:
    return Points.of(rows_of(points))


def sigmas(group: Sequence[Reading], noise: NoiseModel | None) -> np.ndarray:
    """The readings' sigmas under `noise` (None: the configured ones)."""
    if noise is not None and 0 < len(group) <= SMALL_POINT:  # a few readings: plain floats (per point)
        f = Columns(*fields(group))
        return f.sigma * np.array(noise.scales(f.quality.tolist()))
    cols = columns(group)
    return cols.sigma if noise is None else cols.sigma * noise.scale(cols.quality)


def offset_point(built: Built, offset: float) -> Built:
    """A point with a learned bearing offset (rad, offset.py) taken off its bearing."""
    if not offset:
        return built
    point, kept = built
    return replace(point, theta=wrap_pi_float(point.theta - offset)), kept


class PointBatch:
    """The readings of many observation points as flat arrays, with what does not depend on the noise (each
    reading's distance from its point's circular median) worked out once."""

    # turning the readings is a pass of its own
    @metered(BATCH_MADE, lambda self, *_args, **_kw: (1 + self.course) * (self.of.size + 4 * self.sizes.size))
    def __init__(self, groups: Sequence[Sequence[Reading]], cfg: LocalizerConfig, course: bool = False):
        """`course`: each bearing turned by the vehicle's course (course.py), for bearings from its forward axis."""
        self.cfg, self.course = cfg, course
        if course:
            groups = _turned([columns(g) for g in groups])
        self.groups, cols = groups, [columns(g) for g in groups]
        self.sizes = np.array([c.stamp.size for c in cols], int)
        self.of = np.repeat(np.arange(len(cols)), self.sizes)  # each reading's point
        # Made element by element, not concatenated: the noise fit's sums are the same to the last bit as before the
        # checks could run in a worker (with concatenated arrays they changed with the heap's layout).
        self.cols = Columns(*(np.array([v for c in cols for v in getattr(c, name).tolist()], float)
                              for name in Columns._fields))
        self.off_median = self._off_median(cols)

    def _off_median(self, cols: list[Columns]) -> np.ndarray:
        """Each reading's angular distance from its point's circular median; 0 where the gate does not apply
        (fewer than 3 readings, or no gate). Points of one size are worked out together."""
        off = np.zeros(self.of.size)
        if self.cfg.point_gate_sigma <= 0 or not cols:
            return off
        start = np.concatenate([[0], np.cumsum(self.sizes)[:-1]])
        for n in np.unique(self.sizes[self.sizes >= 3]).tolist():
            which = np.flatnonzero(self.sizes == n)
            idx = start[which][:, None] + np.arange(n)[None, :]  # (points, n)
            theta = self.cols.theta[idx]
            spread = np.abs(wrap_pi(theta[:, :, None] - theta[:, None, :])).sum(axis=2)
            first = np.argmax(spread <= spread.min(axis=1, keepdims=True) + TIE_RAD, axis=1)
            median = theta[np.arange(which.size), first]
            off[idx] = np.abs(wrap_pi(theta - median[:, None]))
        return off

    @metered(POINTS_MADE, lambda self, noise, offset: self.cols.theta.size)
    def _made(self, noise: NoiseModel | None, offset: float):
        """The points' fields under `noise` (None: the configured sigmas) with `offset` (rad) taken off, and the
        mask of the readings kept."""
        cfg, c, of, k = self.cfg, self.cols, self.of, self.sizes.size
        own = c.sigma
        sigma = own if noise is None else own * noise.scale(c.quality)
        # the gate is never stricter than the configured sigma (make_point_arrays says why)
        keep = ~(self.off_median > cfg.point_gate_sigma * np.maximum(sigma, own))
        w = np.where(keep, 1.0 / sigma**2 if cfg.point_weighting == "inverse_variance" else 1.0, 0.0)
        a = w / np.bincount(of, w, k)[of]

        def mean_of(values: np.ndarray) -> np.ndarray:
            return np.bincount(of, a * values, k)

        ref = np.arctan2(np.bincount(of, np.where(keep, np.sin(c.theta), 0.0), k),
                         np.bincount(of, np.where(keep, np.cos(c.theta), 0.0), k))
        theta = wrap_pi(ref + mean_of(wrap_pi(c.theta - ref[of])))
        rho, common, heading = cfg.df_correlation, mean_of(sigma), mean_of(c.heading_sigma)
        share = noise.heading_scale if noise is not None else 1.0  # of the stated heading variance (noise.py)
        var = rho * common * common + (1.0 - rho) * np.bincount(of, (a * sigma) ** 2, k) + share * heading * heading
        fields = dict(stamp=mean_of(c.stamp), east=mean_of(c.east), north=mean_of(c.north),
                      theta=wrap_pi(theta - offset) if offset else theta, sigma=np.sqrt(var),
                      n_readings=np.bincount(of, keep, k).astype(int), gps_sigma=mean_of(c.gps_sigma))
        return fields, keep

    def velocity(self) -> np.ndarray:
        """The vehicle's mean east/north velocity over each point's readings (K, 2), m/s."""
        k = self.sizes.size
        sizes = np.maximum(self.sizes, 1)
        return np.column_stack([np.bincount(self.of, self.cols.v_east, k) / sizes,
                                np.bincount(self.of, self.cols.v_north, k) / sizes])

    def points(self, noise: NoiseModel | None, offset: float = 0.0) -> Points:
        """The points as the global search reads them."""
        if self.cfg.point_weighting == "paper":
            return points_of([p for p, _ in self.built(noise, offset)])
        f, _ = self._made(noise, offset)
        return Points(f["east"], f["north"], f["theta"], f["sigma"], f["gps_sigma"])

    def built(self, noise: NoiseModel | None, offset: float = 0.0) -> list[Built]:
        """Each point and the mask of its readings kept, as make_point gives them (the track takes these)."""
        if self.cfg.point_weighting == "paper":  # its coefficients are a recursion per point: the reference's
            share = noise.heading_scale if noise is not None else 1.0
            return [offset_point(make_point(g, self.cfg, sigmas(g, noise), share), offset) for g in self.groups]
        f, keep = self._made(noise, offset)
        rows = zip(*(f[name].tolist() for name in _POINT_FIELDS), strict=True)
        masks = np.split(keep, np.cumsum(self.sizes)[:-1]) if self.sizes.size else []
        return [(ObservationPoint(*row), mask) for row, mask in zip(rows, masks, strict=True)]


def _turned(cols: list[Columns]) -> list[Group]:
    """Each group's readings (fields only) with their bearings turned by the vehicle's course, held over slow
    readings across the groups in turn (course.py)."""
    turn = np.split(group_courses(cols), np.cumsum([c.stamp.size for c in cols])[:-1]) if cols else []
    return [turned_group(c, t) for c, t in zip(cols, turn, strict=True)]


_POINT_FIELDS = ("stamp", "east", "north", "theta", "sigma", "n_readings", "gps_sigma")  # ObservationPoint's order
