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
_MEAN_RADIUS_M = 6_371_008.8
_SKEW_FROM_M = 30_000.0  # nearer the datum the plane turns a bearing by under 0.0003 deg: left out
_GROUND_ITERATIONS = 3  # Newton steps from the sphere's guess: the ellipsoid's altitude to a millimetre at 5000 km


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


def centroid(lat_deg, lon_deg) -> tuple[float, float]:
    """The (lat, lon) of the mean of the points' unit vectors: a frame origin that stays among the points across
    the antimeridian and near a pole, where the plain mean of the longitudes lands half a world away."""
    lat, lon = np.radians(np.asarray(lat_deg, float)), np.radians(np.asarray(lon_deg, float))
    x, y, z = (np.mean(np.cos(lat) * np.cos(lon)), np.mean(np.cos(lat) * np.sin(lon)), np.mean(np.sin(lat)))
    return math.degrees(math.atan2(z, math.hypot(x, y))), math.degrees(math.atan2(y, x))


def azimuth_to_enu(azimuth_deg, north_angle=np.pi / 2):
    """DF azimuth (deg, clockwise from true north) to an ENU angle (rad, CCW from east).

    `north_angle` is the ENU angle of true north at the antenna (pi/2 at the datum; slightly
    different away from it, see LocalFrame.north_angle).
    """
    if _is_scalar(azimuth_deg, north_angle):
        return wrap_pi(north_angle - math.radians(azimuth_deg))
    return wrap_pi(north_angle - np.radians(azimuth_deg))


Skew = tuple[float, float] | None


def turn(base: float, offset: float, skew: Skew) -> float:
    """The map angle (rad) of the direction `offset` rad counter-clockwise, on the ground, from the one whose map
    angle is `base`, at a place whose `skew` LocalFrame.skew gave: the plane foreshortens the direction away from
    the datum by the cosine of the arc (11 % at 3000 km), so far away a turn on the ground is not the same turn on
    the map. A sphere's orthographic projection: north (`base` the north angle, `offset` 0) stays exact."""
    if skew is None:
        return wrap_pi_float(base + offset)
    away, c = skew
    d = base - away
    local = math.atan2(c * math.sin(d), math.cos(d)) + offset
    return wrap_pi_float(away + math.atan2(math.sin(local), c * math.cos(local)))


def unturn(theta: float, base: float, skew: Skew) -> float:
    """turn's inverse: the ground angle (rad, counter-clockwise) from the direction of map angle `base` to the one
    of map angle `theta`."""
    if skew is None:
        return wrap_pi_float(theta - base)
    away, c = skew
    return wrap_pi_float(math.atan2(c * math.sin(theta - away), math.cos(theta - away))
                         - math.atan2(c * math.sin(base - away), math.cos(base - away)))


def ground_to_map(north_angle: float, skew: Skew) -> np.ndarray:
    """The 2x2 matrix taking an east/north step on the ground at a place to the map plane: the meridian
    convergence's rotation and, far from the datum, the plane's foreshortening (turn). A map covariance C is
    J^-1 C J^-T on the ground there."""
    away, c = (north_angle - math.pi / 2, 1.0) if skew is None else skew
    north = math.atan2(c * math.sin(north_angle - away), math.cos(north_angle - away))
    radial, across = np.array([math.cos(away), math.sin(away)]), np.array([-math.sin(away), math.cos(away)])
    return np.column_stack([c * math.cos(b) * radial + math.sin(b) * across for b in (north - math.pi / 2, north)])


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

    def to_geodetic(self, east, north, alt=None):
        """The place at altitude `alt` (m, default the datum's) whose map coordinates are (east, north): to_enu's
        inverse, so a map point goes down to the ground, not along the plane (which rises above the ground as
        d^2 / 2R: 7 km at 300 km from the datum). Newton steps along the plane's up axis on the altitude."""
        alt = self.alt0 if alt is None else alt
        scalar = _is_scalar(east, north, alt)
        if not scalar:
            east, north, alt = np.broadcast_arrays(*(np.asarray(v, float) for v in (east, north, alt)))
        sqrt = math.sqrt if scalar else np.sqrt
        radius = WGS84_A + self.alt0  # the sphere's guess: the ground falls below the plane as the circle does
        below = radius * radius - (east * east + north * north)  # beyond the horizon (<= 0): the plane's edge
        up = (alt - self.alt0) - (radius - sqrt(max(below, 0.0) if scalar else np.maximum(below, 0.0)))
        for _ in range(_GROUND_ITERATIONS):
            lat, lon, height = self._place(east, north, up)
            up = up - (height - alt) / self._up_cosine(lat, lon)
        lat, lon, height = self._place(east, north, up)
        if scalar:
            return math.degrees(lat), math.degrees(lon), height
        return _out(np.degrees(lat)), _out(np.degrees(lon)), _out(height)

    def _place(self, east, north, up):
        """(east, north, up) in the datum's ENU to geodetic (rad, rad, m): pymap3d's enu2geodetic."""
        (e0, e1, e2), (n0, n1, n2), (u0, u1, u2) = self._rot
        x = self._origin[0] + e0 * east + n0 * north + u0 * up
        y = self._origin[1] + e1 * east + n1 * north + u1 * up
        z = self._origin[2] + e2 * east + n2 * north + u2 * up
        return _geodetic(x, y, z)

    def _up_cosine(self, lat_rad, lon_rad):
        """The cosine between the plane's up axis and the ground's up at a place: how fast altitude follows it."""
        u0, u1, u2 = self._rot[2]
        if _is_scalar(lat_rad, lon_rad):
            c = math.cos(lat_rad)
            return max(u0 * c * math.cos(lon_rad) + u1 * c * math.sin(lon_rad) + u2 * math.sin(lat_rad), 0.05)
        c = np.cos(lat_rad)
        return np.maximum(u0 * c * np.cos(lon_rad) + u1 * c * np.sin(lon_rad) + u2 * np.sin(lat_rad), 0.05)

    @staticmethod
    def skew(east: float, north: float) -> Skew:
        """How the plane bends directions at a map point, for `turn`: the map angle away from the datum and the
        foreshortening along it; None within 30 km of the datum, where it is under 0.0003 deg."""
        r2 = east * east + north * north
        if r2 < _SKEW_FROM_M * _SKEW_FROM_M:
            return None
        return math.atan2(north, east), math.sqrt(max(1.0 - r2 / (_MEAN_RADIUS_M * _MEAN_RADIUS_M), 1e-6))

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
