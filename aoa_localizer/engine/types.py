"""Plain data the engine passes around: GPS fixes, DF readings paired with a position, observation points, estimates."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any, NamedTuple

import numpy as np

# A reading's own sigma outside this is no bearing's: below a thousandth of a degree (3.6 arcseconds) the
# crossings' information is too large for double precision (a singular matrix at 1e-6 deg), and past 180
# deg a reading says nothing. The survey reader (pooled.stations) refuses the same.
SIGMA_RANGE_DEG = (1e-3, 180.0)
SIGMA_RANGE_RAD = (math.radians(SIGMA_RANGE_DEG[0]), math.radians(SIGMA_RANGE_DEG[1]))


class Input(NamedTuple):
    """One input as a source gives it (Localizer.feed and run): `kind` fix, bearing, bearing_pose or heading (other
    kinds are not the engine's: passed over), `record` its fields by name (those of add_fix, add_bearing and
    add_heading, or a pose bearing's: FixInput, BearingInput, BearingPoseInput, or a bag's records), `station`
    ("": the default one)."""

    kind: str
    record: Any
    station: str = ""


class FixInput(NamedTuple):
    """A GPS fix's fields, as add_fix takes them."""

    stamp: float
    lat: float
    lon: float
    alt: float = math.nan
    status: int = 0
    sigma_m: float = math.nan


class BearingInput(NamedTuple):
    """A DF record's fields, as add_bearing takes them."""

    stamp: float
    azimuth_deg: float
    quality: float = math.nan
    frequency_hz: float = math.nan
    sigma_deg: float = math.nan


class BearingPoseInput(NamedTuple):
    """A bearing as a pose gives it (the `pose` encoding): a REP-103 yaw (rad, counter-clockwise from east at the
    antenna) and its variance (rad^2; NaN or 0: the configured sigma), fed as an Input of kind bearing_pose."""

    stamp: float
    yaw_rad: float
    variance_rad2: float = math.nan


@dataclass(frozen=True)
class Reading:
    """One accepted DF reading, paired with the antenna position interpolated at its stamp (ENU)."""

    stamp: float
    theta: float  # ENU bearing, rad CCW from east
    quality: float  # 0..100, NaN when the receiver did not say
    sigma: float  # standard deviation of this reading's bearing error, rad
    east: float
    north: float
    gps_sigma: float = 0.0  # horizontal sigma of the antenna position from the fixes (m; 0: not known)
    v_east: float = 0.0  # the vehicle's velocity at the stamp (m/s), for the DF clock offset check
    v_north: float = 0.0
    # sigma of the vehicle's heading a vehicle-relative bearing was turned by (rad; 0: none, or exact). The readings
    # of one point share the heading's error, so the point adds it whole, not averaged down.
    heading_sigma: float = 0.0
    station: str = ""  # the station that took it ("": the default one)


@dataclass(frozen=True)
class ObservationPoint:
    """The corrected bearing of one observation point: the filter's measurement (paper sec. 3.2)."""

    stamp: float
    east: float
    north: float
    theta: float  # corrected bearing, ENU rad
    sigma: float  # its standard deviation, rad, from the readings' sigmas and correlation
    n_readings: int
    gps_sigma: float = 0.0  # horizontal sigma of its antenna position (m), from the fixes' covariances


class EstimateState(StrEnum):
    """How far an estimate may be trusted (str-valued: JSON, /diagnostics and the tables carry the words)."""

    TRACKING = "tracking"
    POORLY_DETERMINED = "poorly_determined"  # proper but wide, multi-modal, or few bearings
    SUSPECT = "suspect"  # the model does not fit the bearings


@dataclass(frozen=True)
class Transmitter:
    """One of the transmitters a channel's bearings come from when several share its frequency (co-channel):
    ENU metres at the datum, lat/lon, the 2x2 covariance (m^2), the share of the channel's readings it explains and
    how far it may be trusted."""

    east: float
    north: float
    lat: float
    lon: float
    cov: np.ndarray
    share: float
    state: EstimateState

    def to_json_dict(self) -> dict:
        return {"lat": self.lat, "lon": self.lon, "east": self.east, "north": self.north,
                "cov": [[float(v) for v in row] for row in self.cov], "share": round(self.share, 4),
                "state": self.state}


@dataclass
class Estimate:
    """The emitter estimate after a filter update: ENU metres at the datum, lat/lon and the 2x2 covariance."""

    stamp: float
    east: float
    north: float
    lat: float
    lon: float
    cov: np.ndarray  # 2x2 east/north covariance, m^2
    bearings_used: int
    points_used: int
    ess: float
    algorithm: str
    particles: np.ndarray | None = field(repr=False, default=None)  # (N, 2) east/north
    weights: np.ndarray | None = field(repr=False, default=None)  # (N,), normalised
    # Alternative hypotheses: (east, north, mass) of each posterior mode holding >= 1 % of the cloud
    modes: list = field(default_factory=list)
    noise: dict | None = None  # the self-calibrated noise (Localizer.noise_summary), when calibration is on
    end_of_data: bool = False  # made by Localizer.finish(), the offline end-of-data global check
    channel: str = "default"  # the emitter's channel id (docs/interface.md, "Channels")
    frequency_hz: float = float("nan")  # the channel's frequency (NaN: the default channel, no frequency)
    # `tracking`, `poorly_determined` (proper but wide, multi-modal, or few bearings) or `suspect` (the model does
    # not fit the bearings); `warnings`: plain sentences naming the likely cause and the setting to check
    state: EstimateState = EstimateState.TRACKING
    warnings: list = field(default_factory=list)
    # The survey model's highest-density regions (level -> rings of (lat, lon)); None from the particle filter
    regions: dict | None = field(repr=False, default=None)
    # The covariance as east/north at the emitter itself (m^2, emitter/fix's): `cov` is the map plane's, which
    # the meridian convergence turns and, far from the datum, foreshortens; None: take `cov`
    ground_cov: np.ndarray | None = field(repr=False, default=None)
    # How many transmitters the channel's bearings come from (co-channel, issue 54) and that count's probability
    # (NaN: not counted yet); with two or more, each in `transmitters`, the most heard first
    transmitter_count: int = 1
    count_probability: float = float("nan")
    transmitters: list = field(default_factory=list)
    # Whether the transmitter moves (issue 68): the model the estimate is from (`static` or `moving`), the
    # probability of motion (NaN: not watched yet), and for a moving one its velocity (east, north m/s) and its
    # 2x2 covariance; the place and `cov` are then where it is now
    motion: str = "static"
    motion_probability: float = float("nan")
    velocity: np.ndarray | None = None
    velocity_cov: np.ndarray | None = field(repr=False, default=None)

    def at_transmitter(self, t: Transmitter) -> Estimate:
        """This estimate moved to one of its channel's transmitters (its place and ellipse; no transmitters or
        regions of its own): how the node and the exports show each."""
        return replace(self, east=t.east, north=t.north, lat=t.lat, lon=t.lon, cov=t.cov, transmitters=[],
                       regions=None)

    def to_json_dict(self) -> dict:
        """The JSON-lines record of docs/interface.md (offline replay output)."""
        return {
            "stamp": self.stamp,
            "lat": self.lat,
            "lon": self.lon,
            "east": self.east,
            "north": self.north,
            "cov": [[float(v) for v in row] for row in self.cov],
            "bearings_used": self.bearings_used,
            "points_used": self.points_used,
            "ess": self.ess,
            "algorithm": self.algorithm,
            "modes": [[round(e, 3), round(n, 3), round(m, 4)] for e, n, m in self.modes],
            "noise": self.noise,
            "end_of_data": self.end_of_data,
            "channel": self.channel,
            "frequency_hz": self.frequency_hz if math.isfinite(self.frequency_hz) else None,
            "state": self.state,
            "warnings": list(self.warnings),
            "transmitter_count": self.transmitter_count,
            "count_probability": round(self.count_probability, 4) if math.isfinite(self.count_probability) else None,
            "transmitters": [t.to_json_dict() for t in self.transmitters],
            "motion": self.motion,
            "motion_probability": (round(self.motion_probability, 4) if math.isfinite(self.motion_probability)
                                   else None),
            **({"velocity": [round(float(v), 4) for v in self.velocity],
                "velocity_cov": [[float(v) for v in row] for row in self.velocity_cov]}
               if self.velocity is not None and self.velocity_cov is not None else {}),
            **({"hpd": {f"{100 * lvl:.0f}": [[[round(float(a), 8), round(float(b), 8)] for a, b in ring]
                                            for ring in rings] for lvl, rings in self.regions.items()}}
               if self.regions else {}),
        }
