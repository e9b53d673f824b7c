"""Bearings taken like a survey's, kept so the end of data can hand them to the survey model.

A channel is survey-like when every bearing it used came from a fixed station (a mast, an anchor: its position
given once) or from an antenna standing still (a surveyor at a stop, whose GPS fix comes with each azimuth). At
`finish()`, with `end_of_data_model: survey`, such channels are located by the survey model `locate` runs
(aoa_localizer.pooled, installed by the package as the solver below), so the API, offline replay and `locate`
give one answer for the same bearings (docs/interface.md, "Survey model"). While the data come, a survey-like
channel's estimates are the survey model's too, solved again each time its bearings grow by a quarter or a place
joins (`due`), so the live estimates never rest on readings taken as independent that are not (an anchor's steady
bias at a place). A vehicle's drive is never survey-like; the engine itself never imports the survey model (it sits
above the engine).
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from aoa_localizer.engine.geodesy import LocalFrame, unturn
from aoa_localizer.engine.inference.co_channel import COUNT_GROWTH
from aoa_localizer.engine.types import Estimate, EstimateState, Transmitter

MAX_RECORDS = 20_000  # per channel: more than any survey, and a bound for a node fed for days
LIVE_GROWTH = 1.25  # a live survey fix is made again once the channel's bearings grew by this factor ...
LIVE_PLACES = 3  # ... or a place joined, from this many places on (fewer: no crossing, the filter's estimate)


@dataclass(frozen=True)
class SurveyRecord:
    """One used bearing of a survey-like channel: its channel (the emitter), the station (the receiver) that took
    it, its place (WGS84), its azimuth from true north, and its own sigma (deg; NaN: none given)."""

    channel: str
    station: str
    stamp: float
    lat: float
    lon: float
    azimuth_deg: float
    sigma_deg: float


@dataclass(frozen=True)
class SurveyTransmitter:
    """One of the transmitters a survey id's bearings come from when several share it (co-channel): WGS84, the
    covariance (m^2, east/north), the share of the readings it explains and its state."""

    lat: float
    lon: float
    cov: np.ndarray
    share: float
    state: EstimateState

    def placed(self, frame: LocalFrame) -> Transmitter:
        """The transmitter in `frame`'s ENU metres."""
        east, north = frame.to_enu(self.lat, self.lon)
        return Transmitter(float(east), float(north), self.lat, self.lon, self.cov, self.share, self.state)


@dataclass(frozen=True)
class SurveyCount:
    """How many transmitters an id's bearings come from (aoa_localizer.pooled.transmitters): the count, its
    probability, each transmitter (two or more, the most heard first) and the warnings the count makes."""

    count: int
    probability: float
    transmitters: tuple[SurveyTransmitter, ...]
    warnings: tuple[str, ...]

    def applied(self, state: EstimateState, warnings: list[str]) -> tuple[EstimateState, list[str]]:
        """A fix's state and warnings once the count is known: with two or more transmitters the fix, of every
        bearing, lies between them (poorly determined)."""
        return (state if self.count < 2 else EstimateState.POORLY_DETERMINED), [*warnings, *self.warnings]


@dataclass(frozen=True)
class SurveyFix:
    """The survey model's answer for one channel: WGS84, the covariance (m^2, east/north), state, warnings, how
    many bearings and stations it used, the calibration it pooled and its highest-density regions."""

    lat: float
    lon: float
    cov: np.ndarray
    state: EstimateState
    warnings: list
    bearings: int
    stations: int
    noise: dict  # the pooled calibration of the fix's group: station error, wild share, receivers' biases
    regions: dict  # level -> rings of (lat, lon): the highest-density regions
    count: SurveyCount | None = None  # how many transmitters its bearings come from (None: not counted)


def live_fix(solve: Callable[[list[SurveyRecord], str, int], dict[str, SurveyFix]], records: list[SurveyRecord],
             channel: str, receiver_class: str, max_k: int, last: SurveyCount | None) -> SurveyFix | None:
    """A survey-like channel's live fix by the survey model: its transmitters counted up to `max_k` (1: not
    counted again, `last` count applied). A plain function of its inputs, as the scheduler runs it."""
    fix = solve(records, receiver_class, max_k).get(channel)
    if max_k > 1 or fix is None or last is None:
        return fix
    state, warnings = last.applied(fix.state, fix.warnings)
    return replace(fix, state=state, warnings=warnings, count=last)


def counted(count: SurveyCount | None, frame: LocalFrame) -> dict:
    """An Estimate's count fields (transmitter_count, count_probability, transmitters in `frame`) from a count."""
    if count is None:
        return {}
    return {"transmitter_count": count.count, "count_probability": count.probability,
            "transmitters": [t.placed(frame) for t in count.transmitters]}


class SurveyLog:
    """Per channel, the bearings it used while every one of them was taken like a survey's (kept in the map
    plane: station, stamp, east, north, ENU angle, true north's ENU angle there, own sigma in deg)."""

    def __init__(self):
        self.records: dict[str, list[tuple]] = defaultdict(list)
        self.not_survey: set[str] = set()  # channels that used a bearing from a moving, densely fixed station
        self.places: dict[str, set] = defaultdict(set)  # each channel's antenna places (decimetres)
        self.solved: dict[str, tuple[int, int]] = {}  # (bearings, places) at a channel's last live fix
        self.live: dict[str, Estimate] = {}  # a channel's last live survey estimate
        self.counted: dict[str, tuple[int, SurveyCount | None]] = {}  # bearings at its last count, and the count

    def add(self, channel: str, survey_like: bool, row: tuple) -> None:
        if channel in self.not_survey:
            return
        if not survey_like or len(self.records[channel]) >= MAX_RECORDS:
            self.not_survey.add(channel)
            for kept in (self.records, self.places, self.solved, self.live, self.counted):
                kept.pop(channel, None)
            return
        self.records[channel].append(row)
        self.places[channel].add((round(row[2], 1), round(row[3], 1)))

    def due(self, channel: str) -> bool:
        """Whether a survey-like channel's live fix is to be made (again): from LIVE_PLACES places on, when its
        bearings grew by LIVE_GROWTH or a place joined since the last one."""
        if channel in self.not_survey or len(self.places.get(channel, ())) < LIVE_PLACES:
            return False
        last = self.solved.get(channel)
        now = (len(self.records[channel]), len(self.places[channel]))
        return last is None or now[1] > last[1] or now[0] >= LIVE_GROWTH * last[0]

    def count_due(self, channel: str) -> bool:
        """Whether a live fix counts the channel's transmitters again: its first, then whenever its bearings
        doubled (a count costs 0.05-1 s; between, the last one holds)."""
        last = self.counted.get(channel)
        return last is None or len(self.records[channel]) >= COUNT_GROWTH * last[0]

    def mark_solved(self, channel: str) -> None:
        self.solved[channel] = (len(self.records[channel]), len(self.places[channel]))

    def survey_records(self, frame: LocalFrame, only: str | None = None) -> list[SurveyRecord]:
        """Every survey-like channel's bearings (`only`: that channel's), in WGS84 with azimuths from true north."""
        out = []
        for channel, rows in self.records.items():
            if not rows or channel in self.not_survey or (only is not None and channel != only):
                continue
            station, stamp, east, north, theta, north_angle, sigma = (list(c) for c in zip(*rows, strict=True))
            lat, lon, _ = frame.to_geodetic(np.array(east), np.array(north))
            # the turn from north on the ground, which far from the datum is not the turn on the map (geodesy.turn)
            azimuth = [math.degrees(-unturn(t, a, LocalFrame.skew(e, n))) % 360.0
                       for t, a, e, n in zip(theta, north_angle, east, north, strict=True)]
            out += [SurveyRecord(channel, s, t, float(a), float(o), float(z), g)
                    for s, t, a, o, z, g in zip(station, stamp, np.atleast_1d(lat), np.atleast_1d(lon),
                                                np.atleast_1d(azimuth), sigma, strict=True)]
        return out

    def clear(self) -> None:
        for kept in (self.records, self.not_survey, self.places, self.solved, self.live, self.counted):
            kept.clear()


def survey_sentence(noise: dict) -> str:
    """'survey model: station error 7.0 deg (90 %: 6.9-7.0), 2 % of stations wild over 27 emitters; receiver
    survey: bias +0.4 +- 0.5 deg' from a survey fix's calibration."""
    if "scale_deg" not in noise:
        return "survey model: not calibrated"
    low, high = noise["scale_deg_90"]
    text = (f"survey model: station error {noise['scale_deg']:.1f} deg (90 %: {low:.1f}-{high:.1f}), "
            f"{100 * noise['wild_share']:.0f} % of stations wild, over {noise['emitters']} emitters")
    for name, b in noise.get("receiver_biases", {}).items():
        if b["bias_deg"] == b["bias_deg"]:  # learned (not NaN)
            text += f"; receiver {name or 'default'}: bias {b['bias_deg']:+.1f} +- {b['bias_sd_deg']:.1f} deg"
    return text
