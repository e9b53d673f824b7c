"""WGS84 <-> local east-north-up plane, DF azimuths <-> ENU angles, wrapped and circular angle maths.

Geodesy is pymap3d's (exact ellipsoidal transforms); this module only fixes the conventions:
ENU metres at a datum, azimuths in degrees clockwise from true north, ENU angles in radians
counter-clockwise from east (REP-103).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d

TWO_PI = 2.0 * np.pi
# A step north used to find the direction of true north at a point (metres, as degrees of latitude).
_NORTH_PROBE_DEG = 1e-4


def wrap_pi(angle):
    """Wrap radians into [-pi, pi): the residual convention for bearing errors."""
    return (np.asarray(angle) + np.pi) % TWO_PI - np.pi


def wrap_360(deg):
    """Wrap degrees into [0, 360): the azimuth convention of a DF record."""
    return np.asarray(deg) % 360.0


def circular_mean(angles, weights=None) -> float:
    """Weighted circular mean of radians (359 deg and 1 deg average to 0, not 180)."""
    angles = np.asarray(angles, dtype=float)
    w = np.ones_like(angles) if weights is None else np.asarray(weights, dtype=float)
    return float(np.arctan2(np.sum(w * np.sin(angles)), np.sum(w * np.cos(angles))))


def azimuth_to_enu(azimuth_deg, north_angle=np.pi / 2):
    """DF azimuth (deg, clockwise from true north) to an ENU angle (rad, CCW from east).

    `north_angle` is the ENU angle of true north at the antenna (pi/2 at the datum; slightly
    different away from it, see LocalFrame.north_angle).
    """
    return wrap_pi(north_angle - np.radians(azimuth_deg))


def enu_to_azimuth(theta, north_angle=np.pi / 2):
    """ENU angle (rad, CCW from east) to a DF azimuth in [0, 360) degrees."""
    return wrap_360(np.degrees(north_angle - np.asarray(theta)))


@dataclass(frozen=True)
class LocalFrame:
    """A local ENU tangent plane at a WGS84 datum (REP-105 `map`)."""

    lat0: float
    lon0: float
    alt0: float = 0.0

    def to_enu(self, lat, lon, alt=None):
        """Latitude/longitude (deg) and altitude (m, default the datum's) to (east, north) metres."""
        alt = self.alt0 if alt is None else alt
        e, n, _ = pymap3d.geodetic2enu(lat, lon, alt, self.lat0, self.lon0, self.alt0)
        return e, n

    def to_geodetic(self, east, north, up=0.0):
        """(east, north[, up]) metres to (lat, lon, alt)."""
        return pymap3d.enu2geodetic(east, north, up, self.lat0, self.lon0, self.alt0)

    def north_angle(self, lat, lon):
        """ENU angle of true north at (lat, lon): pi/2 at the datum, off by the meridian convergence elsewhere."""
        e0, n0 = self.to_enu(lat, lon)
        e1, n1 = self.to_enu(np.asarray(lat) + _NORTH_PROBE_DEG, lon)
        return np.arctan2(np.asarray(n1) - n0, np.asarray(e1) - e0)
