"""Bearings taken at sites of their own (a surveyor's stops, fixed masts) fed to a Localizer, `locate --model
filter`'s path, and the plain least-squares triangulation every survey figure is compared with."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference.triangulation import least_squares_crossing
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.types import Estimate

# A survey is a handful of bearings, so a larger cloud costs well under a second and takes the Monte Carlo
# spread of the estimate (tens of metres at the default 100 on a kilometre-wide posterior) below the data's.
SURVEY_PARTICLES = 2000


def survey_config(**changes) -> LocalizerConfig:
    """`locate --model filter`'s defaults: the engine's, with SURVEY_PARTICLES particles, and the particle filter's
    own end of data (not the survey model's)."""
    return LocalizerConfig(num_particles=SURVEY_PARTICLES, end_of_data_model="filter").with_changes(**changes)


def least_squares_fix(stations: np.ndarray, azimuth_deg: np.ndarray) -> np.ndarray | None:
    """The point nearest all bearing lines (perpendicular distances, plain least squares); None when parallel."""
    return least_squares_crossing(np.asarray(stations, float), np.radians(90.0 - np.asarray(azimuth_deg, float)))


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
        loc.add_station(b.site, fixed=True, position=(b.lat, b.lon))
        # a bearing with its own sigma is taken at it alone, its quality unused
        quality = b.quality if math.isnan(b.sigma_deg) else math.nan
        loc.add_bearing(b.stamp, b.azimuth_deg, quality, station=b.site, sigma_deg=b.sigma_deg)
    loc.flush()
    est = loc.finish() or loc.view(light=True).estimate
    loc.close()
    return est, loc
