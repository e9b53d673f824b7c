"""WGS84 <-> local east-north-up plane, DF azimuths <-> ENU angles, wrapped and circular angle maths.

pymap3d is the reference for the ellipsoidal transforms. `LocalFrame` computes the same ones on the hot path with
the datum's ECEF position and rotation precomputed and plain scalar maths for one point (about 10x faster than
pymap3d's per-call set-up); tests hold the two to 1e-9 deg and 1e-6 m. Conventions: ENU metres at a datum,
azimuths in degrees clockwise from true north, ENU angles in radians counter-clockwise from east (REP-103).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

TWO_PI = 2.0 * np.pi
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
_ECEF_ITERATIONS = 5  # ECEF -> latitude fixed point: converged to 1e-12 rad within 10 km of the surface


def _is_scalar(*values) -> bool:
    for v in values:  # a loop, not all(...): this runs per reading
        if not isinstance(v, float | int):
            return False
    return True


def _ecef(lat_rad, lon_rad, alt):
    """Geodetic (rad, rad, m) to ECEF (m), scalar (math) or array (numpy)."""
    if _is_scalar(lat_rad, lon_rad, alt):
        sin_lat, cos_lat = math.sin(lat_rad), math.cos(lat_rad)
        n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
        return ((n + alt) * cos_lat * math.cos(lon_rad), (n + alt) * cos_lat * math.sin(lon_rad),
                (n * (1.0 - WGS84_E2) + alt) * sin_lat)
    sin_lat = np.sin(lat_rad)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
    cos_lat = np.cos(lat_rad)
    return ((n + alt) * cos_lat * np.cos(lon_rad), (n + alt) * cos_lat * np.sin(lon_rad),
            (n * (1.0 - WGS84_E2) + alt) * sin_lat)


def _geodetic(x, y, z):
    """ECEF (m) to geodetic (rad, rad, m): the latitude by fixed-point iteration from the spherical guess."""
    if _is_scalar(x, y, z):
        return _geodetic_scalar(x, y, z)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(_ECEF_ITERATIONS):
        sin_lat = np.sin(lat)
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
        alt = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + alt)))
    sin_lat = np.sin(lat)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
    return lat, np.arctan2(y, x), p / np.cos(lat) - n


def _geodetic_scalar(x: float, y: float, z: float) -> tuple[float, float, float]:
    """_geodetic for one point, in plain floats (the node's per-estimate call)."""
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1.0 - WGS84_E2))
    n = alt = 0.0
    for _ in range(_ECEF_ITERATIONS):  # the same iterations as the array path
        sin_lat = math.sin(lat)
        n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
        alt = p / math.cos(lat) - n
        lat = math.atan2(z, p * (1.0 - WGS84_E2 * n / (n + alt)))
    sin_lat = math.sin(lat)
    n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
    return lat, math.atan2(y, x), p / math.cos(lat) - n


def wrap_pi(angle):
    """Wrap radians into [-pi, pi): the residual convention for bearing errors. A float gives a float (math: the
    per-reading path), the same value numpy gives."""
    if _is_scalar(angle):
        return wrap_pi_float(angle)
    return (np.asarray(angle) + np.pi) % TWO_PI - np.pi


def wrap_pi_float(angle: float) -> float:
    """wrap_pi for a float, without the type test (the per-reading and per-point loops)."""
    return (angle + math.pi) % TWO_PI - math.pi


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
    if _is_scalar(azimuth_deg, north_angle):
        return wrap_pi(north_angle - math.radians(azimuth_deg))
    return wrap_pi(north_angle - np.radians(azimuth_deg))


def enu_to_azimuth(theta, north_angle=np.pi / 2):
    """ENU angle (rad, CCW from east) to a DF azimuth in [0, 360) degrees."""
    return wrap_360(np.degrees(north_angle - np.asarray(theta)))


@dataclass(frozen=True)
class LocalFrame:
    """A local ENU tangent plane at a WGS84 datum (REP-105 `map`). Scalars in, floats out; arrays in, arrays out."""

    lat0: float
    lon0: float
    alt0: float = 0.0
    _origin: tuple = field(init=False, repr=False, compare=False)  # the datum in ECEF (m)
    _rot: tuple = field(init=False, repr=False, compare=False)  # ECEF -> ENU rotation, rows east, north, up

    def __post_init__(self):
        phi, lam = math.radians(self.lat0), math.radians(self.lon0)
        sp, cp, sl, cl = math.sin(phi), math.cos(phi), math.sin(lam), math.cos(lam)
        object.__setattr__(self, "_origin", tuple(float(v) for v in _ecef(phi, lam, self.alt0)))
        object.__setattr__(self, "_rot", ((-sl, cl, 0.0), (-sp * cl, -sp * sl, cp), (cp * cl, cp * sl, sp)))

    def to_enu(self, lat, lon, alt=None):
        """Latitude/longitude (deg) and altitude (m, default the datum's) to (east, north) metres."""
        alt = self.alt0 if alt is None else alt
        if _is_scalar(lat, lon, alt):
            x, y, z = _ecef(math.radians(lat), math.radians(lon), float(alt))
        else:
            x, y, z = _ecef(np.radians(lat), np.radians(lon), alt)
        dx, dy, dz = x - self._origin[0], y - self._origin[1], z - self._origin[2]
        (e0, e1, _), (n0, n1, n2), _ = self._rot
        if _is_scalar(dx, dy, dz):
            return e0 * dx + e1 * dy, n0 * dx + n1 * dy + n2 * dz
        return _out(e0 * dx + e1 * dy), _out(n0 * dx + n1 * dy + n2 * dz)

    def to_geodetic(self, east, north, up=0.0):
        """(east, north[, up]) metres to (lat, lon, alt)."""
        (e0, e1, e2), (n0, n1, n2), (u0, u1, u2) = self._rot
        if not _is_scalar(east, north, up):
            east, north, up = np.asarray(east, float), np.asarray(north, float), np.asarray(up, float)
        x = self._origin[0] + e0 * east + n0 * north + u0 * up
        y = self._origin[1] + e1 * east + n1 * north + u1 * up
        z = self._origin[2] + e2 * east + n2 * north + u2 * up
        lat, lon, alt = _geodetic(x, y, z)
        if _is_scalar(lat, lon, alt):
            return math.degrees(lat), math.degrees(lon), alt
        return _out(np.degrees(lat)), _out(np.degrees(lon)), _out(alt)

    def north_angle(self, lat, lon):
        """ENU angle of true north at (lat, lon): pi/2 at the datum, off by the meridian convergence elsewhere
        (the local north unit vector, rotated into the datum's plane)."""
        (e0, e1, _), (n0, n1, n2), _ = self._rot
        if _is_scalar(lat, lon):
            phi, lam = math.radians(lat), math.radians(lon)
            nx, ny, nz = -math.sin(phi) * math.cos(lam), -math.sin(phi) * math.sin(lam), math.cos(phi)
            return math.atan2(n0 * nx + n1 * ny + n2 * nz, e0 * nx + e1 * ny)
        phi, lam = np.radians(lat), np.radians(lon)
        nx, ny, nz = -np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)
        return _out(np.arctan2(n0 * nx + n1 * ny + n2 * nz, e0 * nx + e1 * ny))


def _out(v):
    """A 0-d result as a Python float, an array as it is."""
    v = np.asarray(v)
    return float(v) if v.ndim == 0 else v
