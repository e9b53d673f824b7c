"""How many transmitters one survey id's bearings come from (issue 54), by the engine's co-channel count
(engine/inference/co_channel.py) with every station a site of steady bias (the survey's station error): a
station whose bearings all miss one way is a biased station, not a second transmitter. Only a station whose own
readings turn between two places, in turns, shows a second one; readings without stamps cannot show turns and are
not counted.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from aoa_localizer.engine.geodesy import azimuth_to_enu, wrap_pi
from aoa_localizer.engine.inference.co_channel import MIN_READINGS, Place, Readings, count_transmitters, mode_starts
from aoa_localizer.engine.survey.survey_log import SurveyCount, SurveyTransmitter
from aoa_localizer.engine.track.report import co_channel
from aoa_localizer.engine.types import EstimateState
from aoa_localizer.pooled.grid import Geometry
from aoa_localizer.pooled.stations import SurveyReading, unusable

_SCATTER_MIN = 3  # steps from one reading to the next that give a station's own scatter
_MAD_TO_SIGMA = 1.4826
_MAX_READINGS = 500  # more: every k-th reading of each station (a count costs about 0.5 ms a reading)


def count_id(readings: list[SurveyReading], geom: Geometry, point: np.ndarray, site_error: float, max_k: int,
             fix_part: Callable[[list[SurveyReading]], SurveyTransmitter | None]) -> SurveyCount | None:
    """The count of one id's transmitters (1 to `max_k`), from its fix `point` (m, in `geom`'s frame) with each
    reading's own sigma (or its station's scatter from one reading to the next, or else the median of those) and
    each station's bias of sd `site_error` (rad); None below MIN_READINGS usable readings, with a reading without
    a stamp, or with `max_k` < 2. With two or more, each transmitter's place, ellipse and state are `fix_part`'s
    of the readings it took (the survey model's), where it gives one."""
    used = [r for r in readings if unusable(r) is None]
    if max_k < 2 or len(used) < MIN_READINGS or not all(math.isfinite(r.stamp) for r in used):
        return None
    used = _thinned(sorted(used, key=lambda r: r.stamp), math.ceil(len(used) / _MAX_READINGS))
    lat, lon = np.array([r.lat for r in used]), np.array([r.lon for r in used])
    east, north = geom.frame.to_enu(lat, lon)
    sites: dict[tuple, int] = {}
    site = np.array([sites.setdefault(_site_of(r), len(sites)) for r in used])
    theta = azimuth_to_enu(np.array([r.azimuth_deg for r in used]), geom.frame.north_angle(lat, lon))
    own = _successive_scatter(theta, site, len(sites))
    fallback = float(np.median(own[np.isfinite(own)])) if np.any(np.isfinite(own)) else site_error
    sigma = np.array([math.radians(r.sigma_deg) if math.isfinite(r.sigma_deg)
                      else own[s] if math.isfinite(own[s]) else fallback for r, s in zip(used, site, strict=True)])
    heard = Readings(np.array([r.stamp for r in used]), np.asarray(east, float), np.asarray(north, float), theta,
                     np.maximum(sigma, 1e-4), np.full(len(used), np.nan), site, site_error)
    count = count_transmitters(heard, np.asarray(point, float), mode_starts(heard), max_k)
    if count is None:
        return None

    def name(x: np.ndarray) -> str:
        lat, lon, _ = geom.frame.to_geodetic(float(x[0]), float(x[1]))
        return f"{lat:.6f}, {lon:.6f}"

    # Each transmitter is fixed again by the survey model from the readings it took (`fix_part`): the count's own
    # ellipse knows only this id's stations, where the survey model pools their error over every id
    parts = [[r for r, j in zip(used, count.assigned, strict=True) if j == k] for k in range(len(count.transmitters))]
    fixed = [fix_part(part) for part in parts]
    count = replace(count, transmitters=[_placed(geom, place, fix) for place, fix in
                                         zip(count.transmitters, fixed, strict=True)])
    places, warnings = co_channel(count, geom.xy, max_k, name, "the fix of all its bearings, between them")
    out = []
    for (place, state), fix in zip(places, fixed, strict=True):
        lat, lon, _ = geom.frame.to_geodetic(float(place.mean[0]), float(place.mean[1]))
        if fix is not None and fix.state != EstimateState.TRACKING:
            state = fix.state
        out.append(SurveyTransmitter(float(lat), float(lon), place.cov.copy(), place.share, EstimateState(state)))
    return SurveyCount(count.count, count.probability, tuple(out), tuple(warnings))


def _placed(geom: Geometry, place: Place, fix: SurveyTransmitter | None) -> Place:
    """The count's place, or the survey model's fix of its readings where it has one (in `geom`'s frame)."""
    if fix is None:
        return place
    east, north = geom.frame.to_enu(fix.lat, fix.lon)
    return Place(np.array([float(east), float(north)]), fix.cov, place.share)


def _site_of(r: SurveyReading) -> tuple:
    """A reading's station, as the survey model groups them (stations.make_stations)."""
    return r.receiver, r.station, r.lat, r.lon


def _thinned(readings: list[SurveyReading], stride: int) -> list[SurveyReading]:
    """Every `stride`-th reading of each station (so no station is dropped whole by a stride in step with them)."""
    seen: Counter = Counter()
    out = []
    for r in readings:
        if seen[_site_of(r)] % stride == 0:
            out.append(r)
        seen[_site_of(r)] += 1
    return out


def _successive_scatter(theta: np.ndarray, site: np.ndarray, sites: int) -> np.ndarray:
    """Each site's readings' robust sigma from one reading to the next (rad; NaN below _SCATTER_MIN steps): a
    second transmitter's turns change few of the steps, where they would widen the readings' spread about their
    centre, and a steady bias changes none."""
    out = np.full(sites, np.nan)
    for s in range(sites):
        steps = np.abs(wrap_pi(np.diff(theta[site == s])))  # the readings come in time order
        if steps.size >= _SCATTER_MIN:
            out[s] = _MAD_TO_SIGMA * float(np.median(steps)) / math.sqrt(2.0)
    return out
