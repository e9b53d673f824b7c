"""Bearing pre-processing of the AFSA paper (sec. 3.2): quality weights, corrected means, observation points.

A DF receiver at 10 Hz on a moving vehicle gives many readings per place. Readings taken close
together (in time and distance) form one observation point; the point's corrected bearing
(eqs. 19-21) is one filter measurement whose variance is computed from the readings' own
variances and their correlation, so ten readings at one place never count as ten independent looks
unless they are.
"""
from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from operator import attrgetter
from typing import NamedTuple, overload

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import circular_mean, wrap_pi, wrap_pi_float
from aoa_localizer.engine.types import ObservationPoint, Reading


def quality_weight(quality):
    """Bearing error weight W(Q) of eq. 20; the share of a reading's deviation from the mean removed.

    The paper defines Q >= 55. For 40 <= Q < 55 we continue its pattern (offsets 0, 1/8, 1/4 -> 3/8,
    slope denominators 10, 25, 40 -> 55): W = (Q-40)/(55*15) + 3/8, and use the same line below 40.
    Unknown quality (NaN) gets W = 0: no correction. As printed, eq. 20 is discontinuous and not monotone: W
    jumps from 0.165 at Q = 84.9 down to 0 at Q = 85, so W(84.9) = 0.165 > W(70) = 0.125 (a better reading
    corrected more than a worse one). Implemented as printed; `point_weighting: inverse_variance` (the default
    since round 2) does not use it.
    """
    q = np.asarray(quality, dtype=float)
    w = np.where(q >= 85, (q - 85) / (10 * 15),
        np.where(q >= 70, (q - 70) / (25 * 15) + 1 / 8,
        np.where(q >= 55, (q - 55) / (40 * 15) + 1 / 4,
                 (q - 40) / (55 * 15) + 3 / 8)))
    return np.where(np.isnan(q), 0.0, w)


def reading_sigma(quality: float, cfg: LocalizerConfig) -> float:
    """Standard deviation (rad) of one reading's bearing error under the configured noise model."""
    if cfg.sigma_model == "constant":
        return math.radians(cfg.bearing_sigma_deg)
    # Linear in quality between the two calibration points, flat outside them; NaN quality -> the Q=40 value.
    q = 40.0 if math.isnan(quality) else min(max(quality, 40.0), 100.0)
    return math.radians(cfg.sigma_q40_deg + (cfg.sigma_q100_deg - cfg.sigma_q40_deg) * (q - 40.0) / 60.0)


def corrected_mean_coefficients(weights) -> np.ndarray:
    """Coefficients a_j with corrected mean = sum_j a_j gamma_j, for the recursion of eqs. 19-21.

    gamma'_i = gamma_i - (gamma_i - mean_i) W_i with mean_i the running mean of eq. 19, and the
    corrected mean is the mean of the gamma'_i (eq. 21). Expanding gives
    a_j = ((1 - W_j) + sum_{i >= j} W_i / i) / n; the a_j sum to one.
    """
    w = np.asarray(weights, dtype=float)
    n = w.size
    i = np.arange(1, n + 1)
    suffix = np.cumsum((w / i)[::-1])[::-1]
    return ((1.0 - w) + suffix) / n


def point_coefficients(quality: np.ndarray, sigma: np.ndarray, weighting: str) -> np.ndarray:
    """Affine weights of a point's readings: the paper's correction (eqs. 19-21), 1/sigma^2, or equal."""
    if weighting == "paper":
        return corrected_mean_coefficients(quality_weight(quality))
    w = 1.0 / sigma**2 if weighting == "inverse_variance" else np.ones(sigma.size)
    return w / w.sum()


TIE_RAD = 1e-9  # spreads this close are a tie (an even count has two central readings): the first one wins


def point_outliers(theta: np.ndarray, sigma: np.ndarray, gate: float) -> np.ndarray:
    """Mask of readings farther than `gate` sigmas from the point's circular median (needs >= 3 readings)."""
    if gate <= 0 or theta.size < 3:
        return np.zeros(theta.size, dtype=bool)
    return np.abs(wrap_pi(theta - circular_median(theta))) > gate * sigma


def circular_median(theta: np.ndarray) -> float:
    """The reading with the least summed angular distance to the others (both ways of making a point use this)."""
    spread = np.abs(wrap_pi(theta[:, None] - theta[None, :])).sum(axis=1)
    return float(theta[np.flatnonzero(spread <= spread.min() + TIE_RAD)[0]])


def make_point(readings: Sequence[Reading], cfg: LocalizerConfig, sigma: np.ndarray | None = None,
               heading_scale: float = 1.0) -> tuple[ObservationPoint, np.ndarray]:
    """Corrected bearing of one observation point and the mask of the readings it kept (the rest: wild).

    `point_weighting` "paper" is eqs. 19-21; "inverse_variance" is the best linear combination when
    the sigma model is calibrated (sigma_model "quality"). Angles are averaged on the tangent at their circular
    mean, positions and stamps with the same coefficients (the bearing is nearly linear in position over a few
    metres, so the corrected bearing belongs to the equally-weighted position). Variance: a^T C a with C the readings'
    covariance under `df_correlation`. `sigma`: the readings' sigmas when not their own (self-calibrated noise);
    the gate uses the larger of the two. `heading_scale`: the share of the readings' stated heading variance the
    calibration bore out (noise.py). Up to SMALL_POINT readings in plain floats, else (and as the reference)
    make_point_arrays.
    """
    if 0 < len(readings) <= SMALL_POINT and cfg.point_weighting != "paper":
        made = _make_small_point(readings, cfg, sigma, heading_scale)
        if made is not None:
            return made
    return make_point_arrays(readings, cfg, sigma, heading_scale)


def make_point_arrays(readings: Sequence[Reading], cfg: LocalizerConfig, sigma: np.ndarray | None = None,
                      heading_scale: float = 1.0) -> tuple[ObservationPoint, np.ndarray]:
    """make_point in numpy, for any number of readings: the reference the plain-float path is tested against."""
    cols = columns(readings)
    theta, own = cols.theta, cols.sigma
    sigma = own if sigma is None else np.asarray(sigma, float)
    # The gate is never stricter than the configured sigma: the readings of a moving vehicle's point also
    # differ by its motion, which a small calibrated sigma would call wild.
    keep = ~point_outliers(theta, np.maximum(sigma, own), cfg.point_gate_sigma)
    theta, sigma = theta[keep], sigma[keep]
    a = point_coefficients(cols.quality[keep], sigma, cfg.point_weighting)
    ref = circular_mean(theta)
    rho = cfg.df_correlation
    cov = rho * np.outer(sigma, sigma) + (1.0 - rho) * np.diag(sigma**2)
    heading = a @ cols.heading_sigma[keep] * math.sqrt(heading_scale)  # one heading error for the point: whole
    point = ObservationPoint(
        stamp=float(a @ cols.stamp[keep]),
        east=float(a @ cols.east[keep]),
        north=float(a @ cols.north[keep]),
        theta=float(wrap_pi(ref + a @ wrap_pi(theta - ref))),
        sigma=float(math.sqrt(a @ cov @ a + heading * heading)),
        n_readings=int(keep.sum()),
        # GPS errors at one place are the same error: the point's antenna is as uncertain as its readings'.
        gps_sigma=float(a @ cols.gps_sigma[keep]),
    )
    return point, keep


SMALL_POINT = 32  # readings up to which a point is made in plain floats (numpy's per-call cost dominates below)


def _make_small_point(readings: Sequence[Reading], cfg: LocalizerConfig, sigma: np.ndarray | None,
                      heading_scale: float = 1.0) -> tuple[ObservationPoint, np.ndarray] | None:
    """make_point for a few readings in plain floats, the same maths term by term (make_point's numpy code is the
    reference the tests hold this to); None when a sigma is not positive and finite (the reference handles it)."""
    stamp, theta, _, own, east, north, gps, _, _, heading_sigma = field_lists(readings)
    sig = own if sigma is None else sigma.tolist()
    if not all(0.0 < s < math.inf for s in sig) or not all(0.0 < s < math.inf for s in own):
        return None
    n, gate = len(theta), cfg.point_gate_sigma
    keep = [True] * n
    if gate > 0 and n >= 3:
        median = circular_median(np.array(theta))  # the n^2 distances: numpy's per-call cost is the lesser here
        keep = [not abs(wrap_pi_float(t - median)) > gate * max(s, o) for t, s, o in zip(theta, sig, own, strict=True)]
    idx = [i for i in range(n) if keep[i]]
    w = [1.0 / (sig[i] * sig[i]) for i in idx] if cfg.point_weighting == "inverse_variance" else [1.0] * len(idx)
    total = sum(w)
    a = [v / total for v in w]

    def mean_of(values: list[float]) -> float:
        return sum(ai * values[i] for ai, i in zip(a, idx, strict=True))

    ref = math.atan2(sum(math.sin(theta[i]) for i in idx), sum(math.cos(theta[i]) for i in idx))
    rho = cfg.df_correlation
    # a^T C a with C = rho s s^T + (1 - rho) diag(s^2)
    common = mean_of(sig)
    variance = rho * common * common + (1.0 - rho) * sum((ai * sig[i]) ** 2 for ai, i in zip(a, idx, strict=True))
    heading = mean_of(heading_sigma)
    variance += heading * heading * heading_scale
    point = ObservationPoint(
        stamp=mean_of(stamp),
        east=mean_of(east),
        north=mean_of(north),
        theta=wrap_pi_float(ref + sum(ai * wrap_pi_float(theta[i] - ref) for ai, i in zip(a, idx, strict=True))),
        sigma=math.sqrt(variance),
        n_readings=len(idx),
        gps_sigma=mean_of(gps),
    )
    return point, np.array(keep)


def field_lists(group: Sequence[Reading]) -> list[list[float]]:
    """The readings' fields (Columns' order) as lists of floats, from a Group's array or a list's readings: the
    plain-float paths read the same values on both sides of the worker."""
    return fields(group).tolist()


def fields(group: Sequence[Reading]) -> np.ndarray:
    """The readings' fields as one array (Columns' order, one row a field): a Group's own, or made."""
    if isinstance(group, Group):
        return group.block
    return np.array([_FIELDS(r) for r in group], float).reshape(-1, len(Columns._fields)).T


class Columns(NamedTuple):
    """The readings' fields as arrays, one each (separate allocations: the same sums, to the last bit, as arrays
    made field by field)."""

    stamp: np.ndarray
    theta: np.ndarray
    quality: np.ndarray
    sigma: np.ndarray
    east: np.ndarray
    north: np.ndarray
    gps_sigma: np.ndarray
    v_east: np.ndarray
    v_north: np.ndarray
    heading_sigma: np.ndarray


_FIELDS = attrgetter(*Columns._fields)
_FIELD_ROW = {name: i for i, name in enumerate(Columns._fields)}


class Group(Sequence[Reading]):
    """The readings of one observation point, kept as one array of their fields and their stations: a channel
    keeps thousands of readings for its count and noise fits, and a Reading object's floats cost about 350 bytes
    against 80 here. Indexing and iterating give Reading objects again (the same values)."""

    __slots__ = ("block", "stations")

    def __init__(self, readings: Sequence[Reading] = (), cols: Columns | np.ndarray | None = None):
        """From the readings, or from their fields alone (`cols`, or an array of Columns' rows: the worker's and a
        course's turned groups; their station is the default one)."""
        self.stations: str | tuple[str, ...] = ""  # one for all (most groups), or one per reading
        if cols is not None:
            self.block = np.array(cols, float).reshape(len(Columns._fields), -1)
            return
        self.block = np.ascontiguousarray(fields(readings))
        names = tuple(r.station for r in readings)
        self.stations = names if len(set(names)) > 1 else (names[0] if names else "")

    @property
    def cols(self) -> Columns:
        """The fields as arrays, each made anew (as the worker unpacks them: the same sums to the bit)."""
        return Columns(*(row.copy() for row in self.block))

    def station(self, i: int) -> str:
        return self.stations if isinstance(self.stations, str) else self.stations[i]

    def __len__(self) -> int:
        return self.block.shape[1]

    @overload
    def __getitem__(self, i: int) -> Reading: ...

    @overload
    def __getitem__(self, i: slice) -> list[Reading]: ...

    def __getitem__(self, i: int | slice) -> Reading | list[Reading]:
        if isinstance(i, slice):
            return [self[k] for k in range(len(self))[i]]
        k = range(len(self))[i]  # negative indices and bounds as a list's
        return _reading(self.block[:, k].tolist(), self.station(k))

    def __iter__(self) -> Iterator[Reading]:
        return map(_reading, self.block.T.tolist(), stations(self))


def _reading(row: list[float], station: str) -> Reading:
    """A Reading of its fields (Columns' order) and its station."""
    stamp, theta, quality, sigma, east, north, gps_sigma, v_east, v_north, heading_sigma = row
    return Reading(stamp, theta, quality, sigma, east, north, gps_sigma, v_east, v_north, heading_sigma, station)


def first_antenna(group: Sequence[Reading]) -> np.ndarray:
    """(east, north) of the antenna at a group's first reading (a Group's without making a Reading)."""
    return fields(group)[[_FIELD_ROW["east"], _FIELD_ROW["north"]], 0]


def stations(group: Sequence[Reading]) -> list[str]:
    """The station that took each reading."""
    if isinstance(group, Group):
        return [group.station(k) for k in range(len(group))]
    return [r.station for r in group]


def columns(readings: Sequence[Reading]) -> Columns:
    """The readings' fields as arrays."""
    if isinstance(readings, Group):
        return readings.cols
    return Columns(*(row.copy() for row in fields(readings)))  # as the worker unpacks them


class PointBuilder:
    """Groups readings into observation points: a point closes when the next reading is more than
    `obs_max_duration_s` later or `obs_max_distance_m` away from its first reading (or `obs_max_range_share` of the
    first reading's range to `emitter`, the channel's determined estimate: a bearing is nearly linear across a point
    only while the point is small against its range, and a pass close by sweeps it by more than the wild-reading
    gate), when it holds `obs_max_readings`, or on flush(). `first` (0-1] scales those limits for the first point (and
    the first after a flush): channels that share stamps then close their points at different readings instead of all
    in one scan."""

    def __init__(self, cfg: LocalizerConfig, first: float = 1.0):
        self.cfg, self.first = cfg, first
        self.scale = first
        self.readings: list[Reading] = []
        self.emitter: tuple[float, float] | None = None  # the channel's estimate (ENU m), once it has one

    def add(self, r: Reading) -> list[Group]:
        """Add a reading; returns the readings of each point it closed (zero, one or two)."""
        closed = []
        cfg, scale = self.cfg, self.scale
        if self.readings:
            first = self.readings[0]
            span = cfg.obs_max_distance_m
            if self.emitter is not None and cfg.obs_max_range_share > 0.0:
                reach = math.hypot(first.east - self.emitter[0], first.north - self.emitter[1])
                span = min(span, cfg.obs_max_range_share * reach)
            too_late = r.stamp - first.stamp > scale * cfg.obs_max_duration_s
            too_far = math.hypot(r.east - first.east, r.north - first.north) > scale * span
            if too_late or too_far:
                closed.append(self._take())
        self.readings.append(r)
        if len(self.readings) >= max(1.0, scale * cfg.obs_max_readings):
            closed.append(self._take())
        return closed

    def _take(self) -> Group:
        readings, self.readings, self.scale = Group(self.readings), [], 1.0
        return readings

    def flush(self) -> Group | None:
        """Close the open point (end of data, reset) and return its readings (None when none is open); the next
        point is a first point again."""
        taken = self._take() or None
        self.scale = self.first
        return taken
