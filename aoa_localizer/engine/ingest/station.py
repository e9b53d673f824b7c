"""One DF station's inputs: its GPS track (or, for a fixed site, one position), its heading, its stream clocks and
the bearings waiting for a fix after them. A Localizer keeps one per station; the default one is named ""."""
from __future__ import annotations

import heapq
import itertools
import math
from typing import NamedTuple

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.ingest.gps_track import GpsTrack, Where
from aoa_localizer.engine.ingest.heading import ImuHeading, TrackHeading
from aoa_localizer.engine.ingest.input_guard import StreamClock, Verdict
from aoa_localizer.engine.rejections import Reason


class Pending:
    """A bearing waiting for the fix after it: stamp (GPS clock), azimuth (deg), quality, sigma (rad or NaN) and
    its channel's id."""

    __slots__ = ("stamp", "azimuth", "quality", "sigma", "channel")

    def __init__(self, stamp: float, azimuth: float, quality: float, sigma: float, channel: str):
        self.stamp, self.azimuth, self.quality, self.sigma, self.channel = stamp, azimuth, quality, sigma, channel


class Hold(NamedTuple):
    """What became of a DF record handed to its station (Station.hold): the channel clock's verdict (None: not
    asked), the station's own reason for refusing it (None: held, or refused by the verdict), and how many of
    the channel's waiting bearings a clock jump dropped."""

    verdict: Verdict | None
    refused: Reason | None
    dropped: int


class PendingQueue:
    """The bearings waiting for a fix, oldest stamp first (ties in arrival order): a bearing stamped far ahead waits
    at the back, so it never holds up the others (one record on another channel used to stop them all)."""

    def __init__(self):
        self._heap: list[tuple[float, int, Pending]] = []
        self._seq = itertools.count()

    def __len__(self):
        return len(self._heap)

    def push(self, p: Pending):
        heapq.heappush(self._heap, (p.stamp, next(self._seq), p))

    def head(self) -> Pending:
        return self._heap[0][2]

    def pop(self) -> Pending:
        return heapq.heappop(self._heap)[2]

    def drop_channel(self, channel: str) -> int:
        """Drop a channel's bearings (its clock moved to another timeline); returns how many."""
        kept = [entry for entry in self._heap if entry[2].channel != channel]
        dropped = len(self._heap) - len(kept)
        heapq.heapify(kept)
        self._heap = kept
        return dropped

    def clear(self):
        self._heap.clear()


class FixedPlace:
    """A station that does not move: every stamp is located at its one position (ENU), with no velocity."""

    def __init__(self, east: float, north: float, north_angle: float, sigma: float):
        self.at = (east, north, north_angle, sigma, 0.0, 0.0)
        self.t = [-math.inf]  # every stamp is after its "first fix"

    def __len__(self):
        return 1

    def locate(self, _stamp: float) -> tuple[Where, tuple[float, ...]]:
        return Where.OK, self.at


def new_heading(cfg: LocalizerConfig) -> TrackHeading | ImuHeading | None:
    """The heading source for vehicle-relative bearings; None (nothing kept per fix) for the other references."""
    if cfg.bearing_reference != "vehicle":
        return None
    return TrackHeading(cfg) if cfg.heading_source == "track" else ImuHeading(cfg)


class Station:
    """A vehicle (GPS track) or, once `fix_at` is called, a fixed site. `fixed`: its fixes give its position (the
    newest wins) rather than a track."""

    def __init__(self, name: str, cfg: LocalizerConfig, fixed: bool = False):
        self.name, self.cfg, self.fixed = name, cfg, fixed
        self.gps: GpsTrack | FixedPlace = GpsTrack(cfg.gps_max_gap_s)
        self.heading = new_heading(cfg)
        self.pending = PendingQueue()
        self.fix_clock = StreamClock(cfg.max_stamp_jump_s)
        self.df_clocks: dict[str, StreamClock] = {}  # per channel: VFOs of one receiver share their stamps
        self.datum_candidate: tuple[float, float, float, float, float] | None = None  # first fix, until confirmed
        # a fix far ahead of a dense stream, until the next fix says whether the stream paused (it goes on from
        # there: both are used) or it was a glitch (the next is back on the old timeline: it is refused)
        self.held_fix: tuple[float, float, float, float, float] | None = None

    def course_source(self) -> tuple[TrackHeading, GpsTrack] | None:
        """The course-over-ground heading and the track it is fitted to (None: another heading source, or a fixed
        site, which has no course)."""
        if isinstance(self.heading, TrackHeading) and isinstance(self.gps, GpsTrack):
            return self.heading, self.gps
        return None

    def newest_df(self, channel: str) -> float:
        """The newest DF stamp a channel's clock adopted at this station (-inf before any)."""
        clock = self.df_clocks.get(channel)
        return clock.last if clock is not None and clock.last is not None else -math.inf

    def df_clock(self, channel: str) -> StreamClock:
        clock = self.df_clocks.get(channel)
        if clock is None:
            clock = self.df_clocks[channel] = StreamClock(self.cfg.max_stamp_jump_s)
        return clock

    def ahead_of_timeline(self, stamp: float) -> bool:
        """Whether a new channel's first stamp is far ahead (more than max_stamp_jump_s) of this station's dense
        timeline (its fixes', or its other channels' newest stamp): a channel's clock takes any first stamp, so one
        record stamped in 2038 on another frequency would otherwise set the station's newest DF stamp. A fix held
        for its confirmation (a surveyor's next stop) is the timeline such a record is on."""
        if self.held_fix is not None and abs(stamp - self.held_fix[0]) <= self.cfg.max_stamp_jump_s:
            return False
        clocks = [(c.last, c) for c in (self.fix_clock, *self.df_clocks.values()) if c.last is not None]
        if not clocks:
            return False
        last, newest = max(clocks, key=lambda pair: pair[0])
        return not newest.sparse() and stamp - last > self.cfg.max_stamp_jump_s

    def hold(self, channel: str, stamp: float, azimuth: float, quality: float, sigma: float) -> Hold:
        """A checked DF record of `channel` onto this station's timeline, held until a fix places it unless refused:
        a new channel's first stamp far ahead of the timeline (BEARING_STAMP_JUMP, the clock not asked), the channel
        clock's verdict, a stamp before the first fix (BEFORE_FIRST_FIX). On a CLOCK_JUMP the channel's bearings
        waiting on the old timeline are dropped: no fix will place them in order any more."""
        held = Pending(stamp, azimuth, quality, sigma, channel)
        if channel not in self.df_clocks and self.ahead_of_timeline(stamp):
            return Hold(None, Reason.BEARING_STAMP_JUMP, 0)
        verdict = self.df_clock(channel).admit(stamp)
        if verdict not in (Verdict.OK, Verdict.CLOCK_JUMP):
            return Hold(verdict, None, 0)
        dropped = self.pending.drop_channel(channel) if verdict is Verdict.CLOCK_JUMP else 0
        if stamp < self.first_stamp:
            return Hold(verdict, Reason.BEFORE_FIRST_FIX, dropped)
        self.pending.push(held)
        return Hold(verdict, None, dropped)

    def restart_gps(self):
        """A GPS clock jump: the track and the courses start again on the new timeline."""
        if not self.fixed:
            self.gps = GpsTrack(self.cfg.gps_max_gap_s)
        self.heading = new_heading(self.cfg)
        self.datum_candidate = None
        self.held_fix = None

    def fix_at(self, east: float, north: float, north_angle: float, sigma: float):
        """A fixed station's position (a configured one, or its newest fix)."""
        self.gps = FixedPlace(east, north, north_angle, sigma)

    @property
    def first_stamp(self) -> float:
        """The stamp before which no bearing of this station can be placed (inf before any fix)."""
        if len(self.gps):
            return self.gps.t[0]
        return self.datum_candidate[0] if self.datum_candidate is not None else math.inf
