"""Bearings taken like a survey's, kept so the end of data can hand them to the survey model.

A channel is survey-like when every bearing it used came from a fixed station (a mast, an anchor: its position
given once), or came from fixed stations or antennas standing still and its stops show a steady site part (their
readings agree with one another better than with the other stops: `site_part_shown`). A stop alone is no proof of a
site error: a DF crew that stops to read, on clean bearings, keeps the particle engine's exact answer. At
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
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np

from aoa_localizer.engine.distributions import chi2_cdf, chi2_ppf, chi2_sf, norm_ppf, norm_sf
from aoa_localizer.engine.geodesy import LocalFrame, unturn, wrap_pi
from aoa_localizer.engine.inference.co_channel import COUNT_GROWTH
from aoa_localizer.engine.inference.triangulation import least_squares_crossing
from aoa_localizer.engine.points.preprocess import circular_median, point_outliers
from aoa_localizer.engine.types import Estimate, EstimateState, Transmitter

MAX_RECORDS = 20_000  # per channel: more than any survey, and a bound for a node fed for days
LIVE_GROWTH = 1.25  # a live survey fix is made again once the channel's bearings grew by this factor ...
LIVE_PLACES = 3  # ... or a place joined, from this many places on (fewer: no crossing, the filter's estimate)
SITE_READINGS = 3  # a stop tells its own scatter from this many readings on ...
SITE_PLACES = 4  # ... and the site part is judged from this many such stops on (fewer: the readings count alone)
SITE_P = 1e-3  # the stops' centres scattered more than their readings allow at this level: a site part ...
SITE_CLIP = 9.0  # ... each stop's squared standardised residual counted up to this (three sigmas) ...
SITE_RATIO = 2.0  # ... and the typical stop's at least this many times what independent readings give
_PAIR_Q25 = float(norm_ppf(0.625))  # the lower quartile of |a standard normal's draw|
_MEDIAN_VAR = math.pi / 2  # a median's variance over the mean's (its large-sample value; 1.35 for three readings)
_CROSSING_ROUNDS = 5  # the stops' crossing refitted this often, without ...
_CROSSING_TRIM = 0.25  # ... the stops beyond SITE_CLIP, the worst this share of them at most
_WILD_SIGMAS = 4.0  # a reading this many of its sigmas from its stop's median is wild (a point's gate)


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


def site_part_shown(rows: list[tuple]) -> bool | None:
    """Whether a channel's stops show a steady site part: the centres of the stops with SITE_READINGS or more
    readings scatter about their crossing more than the readings' own scatter allows (`_scattered`). Each reading
    counts with its sigma (the quality's, or its own), scaled by what the pairs of readings within a stop say of
    them (a receiver noisier or sharper than configured); a reading _WILD_SIGMAS of its sigmas from its stop's
    median is wild. None where the data cannot tell a site part from the noise (too few such stops). `rows` are
    SurveyLog rows (station, stamp, east, north, map angle, north angle, own sigma in deg, the reading's sigma in
    rad)."""
    places: dict[tuple, list[tuple]] = defaultdict(list)
    for r in rows:
        places[(r[0], round(r[2], 1), round(r[3], 1))].append(r)
    stops = [p for p in places.values() if len(p) >= SITE_READINGS]
    if len(stops) < SITE_PLACES:
        return None
    pairs = []
    for p in stops:
        theta, sigma = np.array([r[4] for r in p]), np.array([r[7] for r in p])
        i, j = np.triu_indices(len(p), 1)
        pairs.append(wrap_pi(theta[i] - theta[j]) / np.hypot(sigma[i], sigma[j]))
    # the sigmas' true multiple, from the pairs' lower quartile: with 40 % wild readings, two pairs of three of a
    # stop's three readings hold a wild one, and a median of the pairs would be a wild pair's
    scale = float(np.quantile(np.abs(np.concatenate(pairs)), 0.25)) / _PAIR_Q25
    if not scale > 0:
        return None
    xy, centres, var = [], [], []
    for p in stops:
        theta, sigma = np.array([r[4] for r in p]), scale * np.array([r[7] for r in p])
        inlier = ~point_outliers(theta, sigma, _WILD_SIGMAS)
        if inlier.sum() < 2:
            continue
        # the median (a reading's worth of the stop's): one reading of three that a reflection's ghost or a wild
        # draw took, within the gate, moves a mean by a third of its error and a median not at all
        centres.append(circular_median(theta[inlier]))
        var.append(_MEDIAN_VAR / float(np.sum(1.0 / sigma[inlier] ** 2)))
        xy.append((p[0][2], p[0][3]))
    if len(xy) < SITE_PLACES:
        return None
    z2 = _stop_residuals(np.array(xy), np.array(centres), np.array(var))
    return None if z2 is None else _scattered(*z2)


def _stop_residuals(xy: np.ndarray, centre: np.ndarray, var: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The stops' squared standardised residuals (their centres' angles about their crossing over their
    variances): at the crossing of every stop, each line weighted by its range's inverse square (an angle's error
    grows with it), and at the crossing refitted without the worst stops beyond SITE_CLIP (up to _CROSSING_TRIM of
    them: the few stops a reflection took over pull the plain crossing and make every other stop look scattered).
    None where the lines are parallel."""
    def z2_at(point: np.ndarray) -> np.ndarray:
        return wrap_pi(centre - np.arctan2(point[1] - xy[:, 1], point[0] - xy[:, 0])) ** 2 / var

    def by_range(point: np.ndarray, kept: np.ndarray) -> np.ndarray | None:
        return least_squares_crossing(xy, centre, kept / np.maximum(np.sum((xy - point) ** 2, axis=1), 1e-6))

    kept = np.ones(len(xy), bool)
    point = least_squares_crossing(xy, centre)
    point = by_range(point, kept) if point is not None else None
    if point is None:
        return None
    plain = trimmed = z2_at(point)
    for _ in range(_CROSSING_ROUNDS):
        worst = np.argsort(-trimmed)[:int(_CROSSING_TRIM * len(trimmed))]
        kept = np.ones(len(xy), bool)
        kept[worst[trimmed[worst] > SITE_CLIP]] = False
        again = by_range(point, kept) if not kept.all() else None
        if again is None:
            break
        point, trimmed = again, z2_at(again)
    return plain, trimmed


def _scattered(z2: np.ndarray, typical: np.ndarray | None = None) -> bool:
    """Whether stops' squared standardised residuals `z2` show a site part that matters: their sum, each clipped at
    SITE_CLIP (a stop that a reflection or wild readings took over counts as one badly off stop, not as a
    hundred), beyond what chi-square(1) draws give at SITE_P (normal approximation to the clipped sum, from its
    exact moments), and the median of `typical` (the same stops' at a crossing the worst do not pull; default
    `z2`) at least SITE_RATIO times chi-square(1)'s: the typical stop scatters, so the filter's ellipse, which takes
    the readings as independent, would be too small by more than sqrt(SITE_RATIO)."""
    c, f1 = SITE_CLIP, float(chi2_sf(SITE_CLIP, 1))
    # x f_1(x) = f_3(x) and x^2 f_1(x) = 3 f_5(x) for chi-square densities: the clipped draw's moments in closed form
    mean = float(chi2_cdf(c, 3)) + c * f1
    var = 3.0 * float(chi2_cdf(c, 5)) + c * c * f1 - mean * mean
    clipped = float(np.minimum(z2, c).sum())
    beyond = float(norm_sf((clipped - z2.size * mean) / math.sqrt(z2.size * var))) < SITE_P
    typical = z2 if typical is None else typical
    return beyond and float(np.median(typical)) >= SITE_RATIO * float(chi2_ppf(0.5, 1))


def counted(count: SurveyCount | None, frame: LocalFrame) -> dict:
    """An Estimate's count fields (transmitter_count, count_probability, transmitters in `frame`) from a count."""
    if count is None:
        return {}
    return {"transmitter_count": count.count, "count_probability": count.probability,
            "transmitters": [t.placed(frame) for t in count.transmitters]}


class SurveyLog:
    """Per channel, the bearings it used while every one of them was taken like a survey's (kept in the map
    plane: station, stamp, east, north, ENU angle, true north's ENU angle there, own sigma in deg, the sigma the
    engine gives the reading in rad)."""

    def __init__(self):
        self.records: dict[str, list[tuple]] = defaultdict(list)
        self.not_survey: set[str] = set()  # channels that used a bearing from a moving, densely fixed station
        self.stopped: set[str] = set()  # channels with a bearing from a standing antenna (not a fixed station)
        self._judged: dict[str, tuple[int, bool | None]] = {}  # a stopped channel's rows when its site part was judged
        self.places: dict[str, set] = defaultdict(set)  # each channel's antenna places (decimetres)

    def add(self, channel: str, fixed: bool, still: bool, row: tuple) -> None:
        """Keep a used bearing's row: from a fixed station, or an antenna standing still; one from a moving antenna
        (or past MAX_RECORDS) makes its channel a drive's for good."""
        if channel in self.not_survey:
            return
        if not (fixed or still) or len(self.records[channel]) >= MAX_RECORDS:
            self.not_survey.add(channel)
            for kept in (self.records, self.places, self._judged):
                kept.pop(channel, None)
            self.stopped.discard(channel)
            return
        if not fixed:
            self.stopped.add(channel)
        self.records[channel].append(row)
        self.places[channel].add((round(row[2], 1), round(row[3], 1)))

    def size(self, channel: str) -> tuple[int, int]:
        """A channel's bearings kept and the places they came from."""
        return len(self.records.get(channel, ())), len(self.places.get(channel, ()))

    def survey_like(self, channel: str, started: bool) -> bool:
        """Whether a kept channel goes to the survey model: every bearing from a fixed station, or its stops show
        a site part (judged again once its rows grew by LIVE_GROWTH), or they cannot tell and its filter has not
        `started` (a surveyor's few single readings: the survey model's fix rather than none)."""
        if channel in self.not_survey or channel not in self.records:
            return False
        if channel not in self.stopped:
            return True
        rows = self.records[channel]
        judged = self._judged.get(channel)
        if judged is None or len(rows) >= LIVE_GROWTH * judged[0]:
            judged = self._judged[channel] = (len(rows), site_part_shown(rows))
        return judged[1] is True or (judged[1] is None and not started)

    def survey_records(self, frame: LocalFrame, channels: Iterable[str]) -> list[SurveyRecord]:
        """The bearings of these channels (the survey-like ones), in WGS84 with azimuths from true north."""
        out = []
        for channel in channels:
            rows = self.records.get(channel)
            if not rows or channel in self.not_survey:
                continue
            station, stamp, east, north, theta, north_angle, sigma, _ = (list(c) for c in zip(*rows, strict=True))
            lat, lon, _ = frame.to_geodetic(np.array(east), np.array(north))
            # the turn from north on the ground, which far from the datum is not the turn on the map (geodesy.turn)
            azimuth = [math.degrees(-unturn(t, a, LocalFrame.skew(e, n))) % 360.0
                       for t, a, e, n in zip(theta, north_angle, east, north, strict=True)]
            out += [SurveyRecord(channel, s, t, float(a), float(o), float(z), g)
                    for s, t, a, o, z, g in zip(station, stamp, np.atleast_1d(lat), np.atleast_1d(lon),
                                                np.atleast_1d(azimuth), sigma, strict=True)]
        return out

    def clear(self) -> None:
        for kept in (self.records, self.not_survey, self.places, self.stopped, self._judged):
            kept.clear()


class LiveFixes:
    """What a survey-like channel's live fixes were made of (the estimates' own; the bearings are the intake's
    SurveyLog): the bearings and places at the last (when to make the next), its estimate, and the bearings at
    the last count with the count."""

    def __init__(self):
        self.solved: dict[str, tuple[int, int]] = {}  # (bearings, places) at a channel's last live fix
        self.live: dict[str, Estimate] = {}  # a channel's last live survey estimate
        self.counted: dict[str, tuple[int, SurveyCount | None]] = {}  # bearings at its last count, and the count

    def due(self, log: SurveyLog, channel: str) -> bool:
        """Whether a survey-like channel's live fix is to be made (again): from LIVE_PLACES places on, when its
        bearings grew by LIVE_GROWTH or a place joined since the last one."""
        now = log.size(channel)
        if channel in log.not_survey or now[1] < LIVE_PLACES:
            return False
        last = self.solved.get(channel)
        return last is None or now[1] > last[1] or now[0] >= LIVE_GROWTH * last[0]

    def count_due(self, log: SurveyLog, channel: str) -> bool:
        """Whether a live fix counts the channel's transmitters again: its first, then whenever its bearings
        doubled (a count costs 0.05-1 s; between, the last one holds)."""
        last = self.counted.get(channel)
        return last is None or log.size(channel)[0] >= COUNT_GROWTH * last[0]

    def solving(self, log: SurveyLog, channel: str, counting: bool) -> SurveyCount | None:
        """A live fix of `channel` begins, counting its transmitters or not: noted; the count it goes on from (None
        when it counts)."""
        self.solved[channel] = log.size(channel)
        if counting:
            self.counted[channel] = (self.solved[channel][0], self.counted.get(channel, (0, None))[1])
            return None
        return self.counted[channel][1]

    def made(self, channel: str, estimate: Estimate | None, count: SurveyCount | None) -> None:
        """A live fix finished: its estimate (None: none published) and the count it made, if it counted."""
        if count is not None and channel in self.counted:
            self.counted[channel] = (self.counted[channel][0], count)
        if estimate is None:
            self.live.pop(channel, None)
        else:
            self.live[channel] = estimate

    def forget(self, channel: str) -> None:
        """The channel is no longer survey-like."""
        self.live.pop(channel, None)


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
