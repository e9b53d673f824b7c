"""Sparse bearing surveys: a few bearings taken by hand or from fixed sites, simulated, fed to a Localizer, and the
plain least-squares triangulation they are compared with.

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
from aoa_localizer.engine.types import Estimate

DATUM = (46.5, -84.3, 200.0)  # a western-hemisphere datum, away from the vehicle scenarios'
# A survey is a handful of bearings, so a larger cloud costs well under a second and takes the Monte Carlo
# spread of the estimate (tens of metres at the default 100 on a kilometre-wide posterior) below the data's.
SURVEY_PARTICLES = 2000


def survey_config(**changes) -> LocalizerConfig:
    """The survey program's defaults: the engine's, with SURVEY_PARTICLES particles."""
    return LocalizerConfig(num_particles=SURVEY_PARTICLES).with_changes(**changes)


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


def least_squares_fix(stations: np.ndarray, azimuth_deg: np.ndarray) -> np.ndarray | None:
    """The point nearest all bearing lines (perpendicular distances, plain least squares); None when parallel."""
    theta = np.radians(90.0 - np.asarray(azimuth_deg, float))
    n = np.column_stack([-np.sin(theta), np.cos(theta)])  # each line's normal
    a = n.T @ n
    if abs(np.linalg.det(a)) < 1e-9:
        return None
    return np.linalg.solve(a, n.T @ np.einsum("ki,ki->k", n, stations))


@dataclass(frozen=True)
class SiteBearing:
    """One bearing taken at a site of its own (a surveyor's stop, a fixed mast): WGS84, azimuth from true north,
    and optionally its quality or its own sigma (deg)."""

    site: str
    stamp: float
    lat: float
    lon: float
    azimuth_deg: float
    quality: float = math.nan
    sigma_deg: float = math.nan


def locate_bearings(bearings: list[SiteBearing], cfg: LocalizerConfig) -> tuple[Estimate | None, Localizer]:
    """One emitter's bearings fed as fixed sites in stamp order; the end-of-data estimate and its Localizer."""
    loc = Localizer(cfg)
    for b in sorted(bearings, key=lambda b: b.stamp):
        loc.set_station_position(b.site, b.lat, b.lon)
        if math.isnan(b.sigma_deg):
            loc.add_bearing(b.stamp, b.azimuth_deg, b.quality, station=b.site)
        else:
            loc.add_bearing_enu(b.stamp, math.radians(90.0 - b.azimuth_deg), math.radians(b.sigma_deg) ** 2,
                                station=b.site)
    loc.flush()
    est = loc.finish() or loc.estimate
    loc.close()
    return est, loc


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
