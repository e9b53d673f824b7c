"""One DF station's inputs: its GPS track (or, for a fixed site, one position), its heading, its stream clocks and
the bearings waiting for a fix after them. A Localizer keeps one per station; the default one is named ""."""
from __future__ import annotations

import math
from collections import deque

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.gps_track import GpsTrack, Where
from aoa_localizer.engine.heading import ImuHeading, TrackHeading
from aoa_localizer.engine.input_guard import StreamClock


class Pending:
    """A bearing waiting for the fix after it: stamp (GPS clock), azimuth (deg), quality, sigma (rad or NaN) and
    its channel's id."""

    __slots__ = ("stamp", "azimuth", "quality", "sigma", "channel")

    def __init__(self, stamp: float, azimuth: float, quality: float, sigma: float, channel: str):
        self.stamp, self.azimuth, self.quality, self.sigma, self.channel = stamp, azimuth, quality, sigma, channel


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
        self.track: GpsTrack | FixedPlace = GpsTrack(cfg.gps_max_gap_s)
        self.heading = new_heading(cfg)
        self.pending: deque[Pending] = deque()
        self.fix_clock = StreamClock(cfg.max_stamp_jump_s)
        self.df_clocks: dict[str, StreamClock] = {}  # per channel: VFOs of one receiver share their stamps
        self.newest_df = -math.inf  # the newest DF stamp of any channel's stream, as its clock follows it
        self.datum_candidate: tuple[float, float, float, float, float] | None = None  # first fix, until confirmed

    def df_clock(self, channel: str) -> StreamClock:
        clock = self.df_clocks.get(channel)
        if clock is None:
            clock = self.df_clocks[channel] = StreamClock(self.cfg.max_stamp_jump_s)
        return clock

    def df_admitted(self, stamp: float, clock_jumped: bool):
        """A DF stamp a channel's clock admitted: `newest_df` follows (recomputed over the channels' clocks when
        one jumped, so a clock step back is followed)."""
        if clock_jumped:
            self.newest_df = max((c.last for c in self.df_clocks.values() if c.last is not None), default=stamp)
        else:
            self.newest_df = max(self.newest_df, stamp)

    def restart_track(self):
        """A GPS clock jump: the track and the courses start again on the new timeline."""
        if not self.fixed:
            self.track = GpsTrack(self.cfg.gps_max_gap_s)
        self.heading = new_heading(self.cfg)
        self.datum_candidate = None

    def fix_at(self, east: float, north: float, north_angle: float, sigma: float):
        """A fixed station's position (a configured one, or its newest fix)."""
        self.track = FixedPlace(east, north, north_angle, sigma)

    @property
    def first_stamp(self) -> float:
        """The stamp before which no bearing of this station can be placed (inf before any fix)."""
        if len(self.track):
            return self.track.t[0]
        return self.datum_candidate[0] if self.datum_candidate is not None else math.inf
