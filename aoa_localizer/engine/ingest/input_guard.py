"""Input guards a single bad message must not get past: stamps off the stream's timeline, implausible fixes.

* `StreamClock`: the timeline of one input stream (fixes, or DF readings). A stamp slightly older than the
  newest is out of order (rejected, as always); a stamp far ahead (`max_stamp_jump_s`) of a dense stream, or
  more than a year ahead of the wall clock, is not adopted as the new newest (one record stamped in 2038 used to
  make every later input "out of order"); a sparse stream (a survey's bearings minutes or hours apart) takes long
  gaps. When the stream really moved to another timeline (a receiver clock stepped back, or forward), `confirm`
  consecutive stamps that agree with each other but not with the old timeline switch it over: `clock_jump`.
* `implausible_fix`: what no vehicle's GPS reports: an altitude outside [-1000, 20000] m, a latitude within
  0.01 deg of a pole (no local north), and (0, 0) exactly, the "null island" of receivers without a fix.
* `confirms`: whether a second fix agrees with a first (the datum is never taken from a single fix).
* `beyond_map`: a place farther from the datum than the map plane serves (3000 km: docs/design.md, "One map
  frame").
"""
from __future__ import annotations

import math
import time
from enum import Enum

from aoa_localizer.engine.rejections import Reason

ALT_RANGE_M = (-1000.0, 20000.0)
POLE_MARGIN_DEG = 0.01
_CONFIRM_DISTANCE_M = 100.0  # two fixes agree when closer than this ...
_CONFIRM_SPEED_MPS = 150.0  # ... plus this speed times the time between them
_EARTH_RADIUS_M = 6_371_000.0
# The map plane holds bearings to a fraction of their noise this far from its datum (tests/test_far_from_datum.py);
# beyond, its foreshortening (26 % at 4500 km) grows past what the engine's turn of the plane corrects well
MAP_REACH_M = 3_000_000.0
_SPARSE_WINDOW = 5  # intervals that tell a sparse stream
# A stamp this far ahead of the wall clock is from no receiver (a year: a computer whose clock lost days or months
# to a missing RTC battery still takes its GPS-stamped inputs)
_FUTURE_MARGIN_S = 366 * 86400.0


class Verdict(Enum):
    """What a stream clock says of a stamp."""

    OK = "ok"
    REPEATED = "repeated"
    OUT_OF_ORDER = "out_of_order"
    AHEAD = "stamp_jump"  # far ahead of the timeline: not adopted
    CLOCK_JUMP = "clock_jump"  # the stream moved to a new timeline: this stamp starts it


class StreamClock:
    """Newest stamp of one input stream, guarded against single stamps off its timeline."""

    def __init__(self, max_jump_s: float, confirm: int = 3):
        self.max_jump_s, self.confirm = max_jump_s, confirm
        self.last: float | None = None
        self.candidates: list[float] = []  # consecutive stamps off the timeline that agree with each other
        self.intervals: list[float] = []  # the latest intervals between adopted stamps

    def admit(self, stamp: float) -> Verdict:
        if self.future(stamp):  # a measurement cannot come from the future
            return Verdict.AHEAD
        if self.last is None or 0 < stamp - self.last <= self.max_jump_s or (stamp > self.last and self.sparse()):
            if self.last is not None and stamp > self.last:
                self.intervals = (self.intervals + [stamp - self.last])[-_SPARSE_WINDOW:]
            self.last = stamp
            self.candidates.clear()
            return Verdict.OK
        if stamp == self.last:
            return Verdict.REPEATED
        if self.candidates and 0 < stamp - self.candidates[-1] <= self.max_jump_s:
            self.candidates.append(stamp)
        else:
            self.candidates = [stamp]
        if len(self.candidates) >= self.confirm:
            self.last = stamp
            self.candidates.clear()
            return Verdict.CLOCK_JUMP
        return Verdict.AHEAD if stamp > self.last else Verdict.OUT_OF_ORDER

    def future(self, stamp: float) -> bool:
        """Whether `stamp` is from no receiver yet: more than a year ahead of the wall clock."""
        return stamp > time.time() + _FUTURE_MARGIN_S

    def far_ahead(self, stamp: float) -> bool:
        """Whether `stamp` is farther ahead of a dense stream's newest than max_jump_s (what admit() refuses as a
        stamp jump; nothing is changed)."""
        return self.last is not None and stamp - self.last > self.max_jump_s and not self.sparse()

    def resume(self, stamp: float) -> None:
        """Go on from `stamp` after a pause the caller confirmed (the stream went on later, not elsewhere)."""
        self.last = stamp
        self.candidates.clear()

    def sparse(self) -> bool:
        """A sparse stream (bearings taken by hand minutes apart, their fixes): a long gap is its rhythm, not a clock
        glitch. Sparse: its median recent interval is over a tenth of max_stamp_jump_s, or it has only one stamp."""
        if not self.intervals:
            return True
        return sorted(self.intervals)[len(self.intervals) // 2] > self.max_jump_s / 10


def implausible_fix(lat: float, lon: float, alt: float) -> Reason | None:
    """Why a finite, in-range fix cannot be a vehicle's position, or None."""
    if math.isfinite(alt) and not ALT_RANGE_M[0] <= alt <= ALT_RANGE_M[1]:
        return Reason.FIX_BAD_ALTITUDE
    if abs(lat) > 90.0 - POLE_MARGIN_DEG:
        return Reason.FIX_NEAR_POLE
    if lat == 0.0 and lon == 0.0:
        return Reason.FIX_NULL_ISLAND
    return None


def beyond_map(datum: tuple[float, float], lat: float, lon: float) -> bool:
    """Whether (lat, lon) is farther than MAP_REACH_M from the map's datum (lat, lon) along the ground."""
    return _arc_m(datum[0], datum[1], lat, lon) > MAP_REACH_M


def _arc_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """The great-circle distance (m) on a sphere of the Earth's mean radius (haversine)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dl = math.radians(lon2 - lon1)
    a = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * _EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(a)))


def confirms(first: tuple[float, float, float], second: tuple[float, float, float], max_gap_s: float) -> bool:
    """Whether fix `second` (stamp, lat, lon) agrees with `first`: at most `max_gap_s` later, and within 100 m
    plus 150 m/s of travel."""
    (t1, lat1, lon1), (t2, lat2, lon2) = first, second
    if not 0 < t2 - t1 <= max_gap_s:
        return False
    return _arc_m(lat1, lon1, lat2, lon2) <= _CONFIRM_DISTANCE_M + _CONFIRM_SPEED_MPS * abs(t2 - t1)


class StampGaps:
    """Counts gaps in a stream's stamps longer than `factor` times its typical interval, the lower quartile of the
    last 50 (a median would itself be a gap once about half the messages are lost): messages lost on the way, or a
    receiver that paused. Needs 10 intervals before it judges."""

    def __init__(self, factor: float = 5.0, window: int = 50):
        self.factor, self.window = factor, window
        self.intervals: list[float] = []
        self.last: float | None = None
        self.gaps = 0
        self.missing = 0  # messages the gaps would have held at the median rate

    def add(self, stamp: float):
        if self.last is not None and stamp > self.last:
            dt = stamp - self.last
            if len(self.intervals) >= 10:
                typical = sorted(self.intervals)[len(self.intervals) // 4]
                if typical > 0 and dt > self.factor * typical:
                    self.gaps += 1
                    self.missing += round(dt / typical) - 1
            self.intervals = (self.intervals + [dt])[-self.window:]
        if self.last is None or stamp > self.last:
            self.last = stamp
