"""Stations and receivers of a survey: which readings share a site error, and which sites share a receiver.

A station is one place (and name) from which one emitter was heard: its readings share one steady error (the
site's multipath, the observer's stance), so they count as one noisy look plus their own scatter, never as many
independent ones. A receiver is what a set of stations share (a common bias, an error scale, a tail weight): a
`receiver` column says which; without one, a file whose every station is a fixed site (one name at one place,
heard for two or more emitters, or with FIXED_SITE_READINGS or more readings of one: a mast network, indoor
anchors) makes each site its own receiver, and any other file (an observer walking, a vehicle) is one receiver.
"""
from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, replace

import numpy as np

from aoa_localizer.engine.geodesy import wrap_pi
from aoa_localizer.engine.types import SIGMA_RANGE_DEG

_MAD_TO_SIGMA = 1.4826  # a Gaussian's sigma over its median absolute deviation
_WILD_Z = 4.0  # a reading this many robust sigmas from its station's median is left out of the station's centre
_OWN_SCATTER_MIN = 5  # readings from which a station's own scatter is trusted over the receiver's pooled one
FIXED_SITE_READINGS = 5  # an instrument left at one place, not an observer taking a bearing and moving on


@dataclass(frozen=True)
class SurveyReading:
    """One bearing: the emitter it is of, the receiver and station that took it (WGS84), its azimuth from true
    north, and optionally its own sigma (deg) and its time (s; the co-channel count needs every reading's)."""

    emitter: str
    lat: float
    lon: float
    azimuth_deg: float
    station: str = ""
    receiver: str = ""
    sigma_deg: float = math.nan
    stamp: float = math.nan


@dataclass(frozen=True)
class Station:
    """One emitter's readings from one place: their robust centre (rad, clockwise from north) and the variance of
    that centre from their own scatter (rad^2; NaN for one reading without a sigma: the receiver's pooled scatter
    is used)."""

    emitter: str
    receiver: str
    name: str
    lat: float
    lon: float
    centre: float
    var: float
    n: int
    scatter: float  # the readings' own robust sigma (rad; NaN below 3 readings)


def _centre(az: np.ndarray, sigma: np.ndarray) -> tuple[float, float, float]:
    """Centre (rad), its variance (rad^2; NaN when unknown) and the readings' robust sigma (NaN below 3). With
    sigmas: their inverse-variance mean. Without, from 3 readings on: the mean of those within _WILD_Z robust sigmas
    of the median (a wild reading left out, the rest used at full efficiency, not the median's pi/2), its variance
    their scatter over their count; fewer: the median, its variance unknown."""
    if np.all(np.isfinite(sigma)):
        w = 1.0 / sigma**2
        mean = math.atan2(float(np.sum(w * np.sin(az))), float(np.sum(w * np.cos(az))))
        return mean, 1.0 / float(np.sum(w)), math.nan
    if az.size == 1:
        return float(az[0]), math.nan, math.nan
    mean = math.atan2(float(np.mean(np.sin(az))), float(np.mean(np.cos(az))))
    median = float(wrap_pi(mean + np.median(wrap_pi(az - mean))))
    if az.size < 3:
        return median, math.nan, math.nan
    scatter = pair_scatter(az)
    dev = wrap_pi(az - median)
    kept = dev[np.abs(dev) <= _WILD_Z * scatter] if scatter > 0 else dev
    centre = float(wrap_pi(median + np.mean(kept)))
    return centre, scatter**2 / kept.size, scatter


def pair_scatter(az: np.ndarray) -> float:
    """The robust sigma (rad) of readings (2 or more) that scatter independently about their centre, from their
    pairs (a pair's difference has twice a reading's variance; the median of the pairs' absolute differences is not
    pulled by a wild reading as a mean is, nor biased low as deviations from a sample's own median are)."""
    i, j = np.triu_indices(az.size, 1)
    return _MAD_TO_SIGMA * float(np.median(np.abs(wrap_pi(az[i] - az[j])))) / math.sqrt(2.0)


def unusable(r: SurveyReading) -> str | None:
    """Why a reading cannot be used, or None."""
    if not (math.isfinite(r.lat) and math.isfinite(r.lon) and abs(r.lat) <= 90 and abs(r.lon) <= 180):
        return f"position {r.lat}, {r.lon} is not a latitude and longitude"
    if not math.isfinite(r.azimuth_deg):
        return f"azimuth {r.azimuth_deg} is not a number"
    if not (math.isnan(r.sigma_deg) or SIGMA_RANGE_DEG[0] <= r.sigma_deg <= SIGMA_RANGE_DEG[1]):
        return f"sigma_deg {r.sigma_deg:g} is not in [{SIGMA_RANGE_DEG[0]:g}, {SIGMA_RANGE_DEG[1]:g}]"
    return None


def make_stations(readings: list[SurveyReading]) -> tuple[list[Station], list[str]]:
    """The survey's stations (readings grouped by emitter, receiver, name and exact place) and a warning for each
    reading that cannot be used (it is left out) and each station name that one emitter heard from two places."""
    groups: dict[tuple, list[SurveyReading]] = defaultdict(list)
    warnings, places = [], defaultdict(set)
    for i, r in enumerate(readings):
        why = unusable(r)
        if why:
            warnings.append(f"reading {i + 1} ({r.emitter or 'emitter'}): {why}; not used")
        else:
            groups[(r.emitter, r.receiver, r.station, r.lat, r.lon)].append(r)
    for emitter, receiver, name, lat, lon in groups:
        if name:
            places[(emitter, receiver, name)].add((lat, lon))
    for (emitter, _, name), where in places.items():
        if len(where) > 1:
            warnings.append(f"{emitter or 'emitter'}: station {name!r} appears at {len(where)} places; each is taken "
                            "as a station of its own")
    stations = []
    for (emitter, receiver, name, lat, lon), rows in groups.items():
        az = np.radians([r.azimuth_deg for r in rows])
        centre, var, scatter = _centre(az, np.radians([r.sigma_deg for r in rows]))
        stations.append(Station(emitter, receiver, name, lat, lon, centre, var, len(rows), scatter))
    return _with_receivers(stations), warnings


def _with_receivers(stations: list[Station]) -> list[Station]:
    """Stations without a receiver named: each fixed site its own receiver when every station is one, else one."""
    unnamed = [s for s in stations if not s.receiver]
    if not unnamed:
        return stations
    heard: dict[str, set] = defaultdict(set)
    where: dict[str, set] = defaultdict(set)
    most: dict[str, int] = defaultdict(int)
    for s in unnamed:
        heard[s.name].add(s.emitter)
        where[s.name].add((s.lat, s.lon))
        most[s.name] = max(most[s.name], s.n)
    sites = all(name and len(where[name]) == 1 and (len(heard[name]) >= 2 or most[name] >= FIXED_SITE_READINGS)
                for name in heard)
    out = []
    for s in stations:
        if s.receiver:
            out.append(s)
        else:
            out.append(replace(s, receiver=f"site {s.name}" if sites else "survey"))
    return out


def pooled_scatter(stations: list[Station]) -> dict[str, float]:
    """Per receiver, the median of its stations' own robust sigmas (rad^2 returned as a variance; 0 where no
    station has 3 readings: then the site error's scale absorbs the readings' scatter)."""
    own: dict[str, list[float]] = defaultdict(list)
    for s in stations:
        if math.isfinite(s.scatter):
            own[s.receiver].append(s.scatter)
    return {r: float(np.median(v)) ** 2 if v else 0.0 for r, v in own.items()}


def station_variance(s: Station, receiver_scatter_var: float) -> float:
    """The variance of a station's centre from its readings' own scatter (rad^2): its own where it has enough
    readings or sigmas, else the receiver's pooled scatter over its readings."""
    if math.isfinite(s.var) and (s.n >= _OWN_SCATTER_MIN or not math.isfinite(s.scatter)):
        return s.var
    return receiver_scatter_var / s.n
