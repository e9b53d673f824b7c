"""Sparse bearing surveys, simulated: a few bearings taken by hand or from fixed sites, and one observer's or a
room's anchors' many emitters, fed to a Localizer (engine/site_bearings.py) or the survey model.

A hand-held radio-telemetry survey (the case docs/benchmarks.md measures): a transmitter at a surveyed place, 3-5
Yagi azimuths from stations 40-700 m away taken minutes apart, noise 20-30 deg, some readings far off, and an
observer's own bias up to +-10 deg. Every station is a fixed site (its position and one bearing).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame, wrap_360
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.site_bearings import SiteBearing, locate_bearings, survey_config
from aoa_localizer.engine.types import Estimate
from aoa_localizer.pooled.stations import SurveyReading

DATUM = (46.5, -84.3, 200.0)  # a western-hemisphere datum, away from the vehicle scenarios'
@dataclass(frozen=True)
class Survey:
    """Stations (K, 2) ENU m at DATUM, their azimuths (deg from true north), stamps (s), the truth (2,)."""

    stations: np.ndarray
    azimuth_deg: np.ndarray
    stamps: np.ndarray
    truth: np.ndarray


def hand_held(rng: np.random.Generator, n_bearings: tuple[int, int] = (3, 5), range_m: tuple[float, float] = (40, 700),
              sigma_deg: tuple[float, float] = (20.0, 30.0), wild_share: float = 1 / 12,
              bias_deg: float = 10.0) -> Survey:
    """One hand-held survey: stations at log-uniform ranges and uniform directions around the truth (at the
    origin), Gaussian noise of a sigma drawn per survey, a share of readings drawn uniformly (wild), one bias per
    observer, bearings 5-120 min apart."""
    k = int(rng.integers(n_bearings[0], n_bearings[1] + 1))
    rng_m = np.exp(rng.uniform(math.log(range_m[0]), math.log(range_m[1]), k))
    ang = rng.uniform(0, 2 * math.pi, k)
    stations = np.column_stack([rng_m * np.cos(ang), rng_m * np.sin(ang)])
    true_az = np.degrees(np.arctan2(-stations[:, 0], -stations[:, 1]))  # clockwise from north, station -> origin
    sigma = rng.uniform(*sigma_deg)
    az = true_az + rng.uniform(-bias_deg, bias_deg) + sigma * rng.standard_normal(k)
    wild = rng.random(k) < wild_share
    az[wild] = rng.uniform(0, 360, int(wild.sum()))
    stamps = 1.7e9 + np.cumsum(rng.uniform(300, 7200, k))
    return Survey(stations, wrap_360(az), stamps, np.zeros(2))


def locate_survey(survey: Survey, cfg: LocalizerConfig | None = None) -> Estimate | None:
    """A simulated survey's end-of-data estimate (datum DATUM; the survey program's defaults unless `cfg`)."""
    return locate_survey_with(survey, cfg)[0]


def locate_survey_with(survey: Survey, cfg: LocalizerConfig | None = None) -> tuple[Estimate | None, Localizer]:
    """locate_survey, with the closed Localizer that made the estimate."""
    frame = LocalFrame(*DATUM)
    bearings = []
    for i, ((e, n), az, t) in enumerate(zip(survey.stations, survey.azimuth_deg, survey.stamps, strict=True)):
        lat, lon, _ = frame.to_geodetic(e, n)
        bearings.append(SiteBearing(f"s{i}", float(t), float(lat), float(lon), float(az)))
    cfg = (cfg or survey_config()).with_changes(datum_lat=DATUM[0], datum_lon=DATUM[1], datum_alt=DATUM[2])
    return locate_bearings(bearings, cfg)


@dataclass(frozen=True)
class SurveySet:
    """Several emitters' bearings: per reading its emitter, station name, place (ENU m) and azimuth (deg), and
    each emitter's truth (ENU m)."""

    emitter: list
    station: list
    places: np.ndarray  # (N, 2)
    azimuth_deg: np.ndarray  # (N,)
    truth: dict


def observer_like(rng: np.random.Generator, emitters: int = 27, bias_deg: float = 10.0, visible_deg: float = 8.0,
                  place_share: tuple = (0.2, 0.6), place_weight: tuple = (0.75, 0.25),
                  wild_share: float = 0.08) -> SurveySet:
    """One observer walking to 3-5 stations 100-700 m from each of several transmitters, built to reproduce what
    two observers' real surveys show (examples/real, docs/design.md): a bias common to all of the observer's
    azimuths, an apparent place per transmitter (the bearings agree on a place beside it, per axis one of
    `place_share` of the range, drawn with `place_weight`, which no crossing shows), a visible scatter, and wild
    azimuths (uniform)."""
    names, stations, places, az, truth = [], [], [], [], {}
    for j in range(emitters):
        t = rng.uniform(-800, 800, 2)
        truth[f"e{j}"] = t
        k = int(rng.integers(3, 6))
        rng_m = rng.uniform(100, 700, k)
        ang = rng.uniform(0, 2 * math.pi, k)
        st = t + np.column_stack([rng_m * np.sin(ang), rng_m * np.cos(ang)])
        share = place_share[int(rng.choice(len(place_share), p=place_weight))]
        apparent = t + rng.normal(0, share * float(np.median(rng_m)), 2)
        a = np.degrees(np.arctan2(apparent[0] - st[:, 0], apparent[1] - st[:, 1])) + bias_deg
        a += visible_deg * rng.standard_normal(k)
        wild = rng.random(k) < wild_share
        a[wild] = rng.uniform(0, 360, int(wild.sum()))
        names += [f"e{j}"] * k
        stations += [f"s{i}" for i in range(k)]
        places.append(st)
        az.append(a)
    return SurveySet(names, stations, np.vstack(places), wrap_360(np.concatenate(az)), truth)


def indoor_anchors(rng: np.random.Generator, places: int = 16, readings: int = 250, site_deg: float = 20.0,
                   mount_deg: float = 10.0, scatter_deg: float = 8.0, wild_share: float = 0.05,
                   summarise: bool = False) -> SurveySet:
    """Four angle-of-arrival anchors in the corners of a 12 m x 6 m room heard at several places: each anchor's
    mount off by N(0, mount_deg) for every place, each anchor's bearings of one place off by a steady N(0,
    site_deg) (multipath there), `readings` readings of it with scatter and wild ones; `summarise`: one median
    bearing per anchor and place."""
    anchors = np.array([[0.0, 0.0], [12.0, 0.0], [12.0, 6.0], [0.0, 6.0]])
    mount = rng.normal(0, mount_deg, 4)
    names, stations, pts, az, truth = [], [], [], [], {}
    for j in range(places):
        t = rng.uniform([1.0, 1.0], [11.0, 5.0])
        truth[f"p{j}"] = t
        for a, (ax, ay) in enumerate(anchors):
            true = math.degrees(math.atan2(t[0] - ax, t[1] - ay))
            b = true + mount[a] + rng.normal(0, site_deg) + scatter_deg * rng.standard_normal(readings)
            wild = rng.random(readings) < wild_share
            b[wild] = rng.uniform(0, 360, int(wild.sum()))
            if summarise:
                b = np.array([true + float(np.median(wrap_360(b - true + 180) - 180))])
            names += [f"p{j}"] * b.size
            stations += [f"A{a}"] * b.size
            pts.append(np.repeat([[ax, ay]], b.size, axis=0))
            az.append(b)
    return SurveySet(names, stations, np.vstack(pts), wrap_360(np.concatenate(az)), truth)


def hand_held_set(rng: np.random.Generator, emitters: int = 60) -> SurveySet:
    """Several hand_held() surveys, each its own transmitter, as one observer's file."""
    names, stations, pts, az, truth = [], [], [], [], {}
    for j in range(emitters):
        s = hand_held(rng)
        off = rng.uniform(-3000, 3000, 2)
        truth[f"h{j}"] = off
        names += [f"h{j}"] * len(s.azimuth_deg)
        stations += [f"s{i}" for i in range(len(s.azimuth_deg))]
        pts.append(s.stations + off)
        az.append(s.azimuth_deg)
    return SurveySet(names, stations, np.vstack(pts), np.concatenate(az), truth)


@dataclass(frozen=True)
class SharedFrequency:
    """Fixed stations' readings of transmitters that share one frequency: per reading its stamp (s), station index
    and azimuth (deg from true north); the stations and the transmitters (ENU m at DATUM), and each reading's
    transmitter."""

    stamps: np.ndarray
    station: np.ndarray
    azimuth_deg: np.ndarray
    stations: np.ndarray
    transmitters: np.ndarray
    source: np.ndarray

    def readings(self, emitter: str = "x") -> list[SurveyReading]:
        """As the survey model's readings (aoa_localizer.pooled), one id, each station named s<i>."""
        frame = LocalFrame(*DATUM)
        places = [frame.to_geodetic(e, n)[:2] for e, n in self.stations]
        return [SurveyReading(emitter, float(places[s][0]), float(places[s][1]), float(az), f"s{s}", stamp=float(t))
                for t, s, az in zip(self.stamps, self.station, self.azimuth_deg, strict=True)]


def shared_frequency(rng: np.random.Generator, transmitters: int = 2, together: bool = True, seconds: float = 600.0,
                     shares: tuple[float, ...] | None = None, apart_m: float = 600.0, stations: int = 6,
                     bias_deg: float = 3.0, scatter_deg: float = 1.5) -> SharedFrequency:
    """Fixed stations 2 km out hearing `transmitters` on one frequency (the first `apart_m` from the last, on a
    line through the centre), each station with a steady bias N(0, bias_deg) and a reading's scatter. `together`:
    every station reads once a second for `seconds` while the transmitters take turns of 5-30 s, each turn's by
    `shares` (air time; equal by default); else a surveyor's stops at each station in turn, 5 min apart, a minute
    of readings at each, turns of 5-20 s."""
    ang = np.arange(stations) * 2.0 * math.pi / stations + rng.uniform(0.0, 2.0 * math.pi / stations)
    st = 2000.0 * np.column_stack([np.cos(ang), np.sin(ang)])
    along = np.linspace(-0.5, 0.5, transmitters) * apart_m if transmitters > 1 else np.zeros(1)
    tx = np.column_stack([along, 0.3 * along])
    bias = rng.normal(0.0, bias_deg, stations)
    p = np.asarray(shares if shares is not None else np.full(transmitters, 1.0 / transmitters), float)
    rows: list[tuple[float, int, int]] = []
    for stop in [None] if together else range(stations):
        t, end = (0.0, seconds) if stop is None else (300.0 * stop, 300.0 * stop + 60.0)
        while t < end:
            length, who = rng.uniform(5.0, 30.0 if stop is None else 20.0), int(rng.choice(transmitters, p=p))
            for u in np.arange(t, t + length):
                rows += [(u + 0.1 * s, s, who) for s in (range(stations) if stop is None else [stop])]
            t += length + rng.uniform(1.0, 10.0)
    stamp, station, source = (np.array(c) for c in zip(*rows, strict=True))
    d = tx[source] - st[station]
    az = np.degrees(np.arctan2(d[:, 0], d[:, 1])) + bias[station] + scatter_deg * rng.standard_normal(len(rows))
    return SharedFrequency(stamp, station, wrap_360(az), st, tx, source)
