import math

import numpy as np
import pytest

from aoa_localizer.engine.geodesy import (
    LocalFrame,
    azimuth_to_enu,
    circular_mean,
    wrap_360,
    wrap_pi,
)


@pytest.mark.parametrize("datum", [(39.1, 117.2, 5.0), (-33.9, -70.6, 520.0), (-12.0, -77.0, 0.0), (51.5, -0.1, 30.0)])
def test_enu_round_trip_is_exact_to_a_centimetre_at_10_km(datum):
    frame = LocalFrame(*datum)
    east = np.array([10_000.0, -10_000.0, 7071.0, 0.0])
    north = np.array([0.0, 10_000.0, -7071.0, -10_000.0])
    lat, lon, alt = frame.to_geodetic(east, north)
    e2, n2 = frame.to_enu(lat, lon, alt)
    assert np.max(np.abs(e2 - east)) < 0.01 and np.max(np.abs(n2 - north)) < 0.01


def test_southern_western_datum_puts_north_and_east_the_right_way(frame):
    f = LocalFrame(-33.9, -70.6, 0.0)
    e, n = f.to_enu(-33.8, -70.6)  # 0.1 deg further north
    assert n == pytest.approx(11_093, rel=2e-3) and abs(e) < 1e-6
    e, n = f.to_enu(-33.9, -70.5)  # 0.1 deg further east: 11.1 km * cos(33.9 deg)
    assert e == pytest.approx(9_245, rel=3e-3) and abs(n) < 5


def test_azimuth_and_enu_angle_conventions():
    assert azimuth_to_enu(0.0) == pytest.approx(np.pi / 2)  # north
    assert azimuth_to_enu(90.0) == pytest.approx(0.0)  # east
    assert azimuth_to_enu(180.0) == pytest.approx(-np.pi / 2)  # south
    assert azimuth_to_enu(270.0) == pytest.approx(-np.pi)  # west, wrapped into [-pi, pi)
    assert enu_to_azimuth(np.pi / 2) == pytest.approx(0.0)
    assert enu_to_azimuth(-np.pi / 2) == pytest.approx(180.0)


@pytest.mark.parametrize("az", [0.0, 359.9, 0.1, 45.0, 180.0, 270.0, 719.5, -10.0])
def test_azimuth_round_trip_wraps_through_north(az):
    back = enu_to_azimuth(azimuth_to_enu(az))
    assert 0.0 <= back < 360.0
    assert (back - az + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-9)


def test_wraps():
    assert wrap_pi(3 * np.pi / 2) == pytest.approx(-np.pi / 2)
    assert wrap_pi(-3 * np.pi / 2) == pytest.approx(np.pi / 2)
    assert wrap_360(-1.0) == pytest.approx(359.0)
    assert wrap_360(721.0) == pytest.approx(1.0)


def test_circular_mean_of_359_and_1_degree_is_north_not_south():
    m = circular_mean(np.radians([359.0, 1.0]))
    assert abs(m) < 1e-12
    assert circular_mean(np.radians([350.0, 10.0, 20.0])) == pytest.approx(np.radians(6.6666), abs=2e-3)
    assert circular_mean(np.radians([0.0, 90.0]), weights=[3.0, 1.0]) == pytest.approx(np.arctan2(1, 3))


def test_north_angle_is_pi_over_two_at_the_datum_and_tilts_with_meridian_convergence():
    f = LocalFrame(39.1, 117.2, 0.0)
    assert f.north_angle(39.1, 117.2) == pytest.approx(np.pi / 2, abs=1e-6)
    # 0.1 deg east: true north leans west of the plane's y axis by about dlon * sin(lat).
    tilt = f.north_angle(39.1, 117.3) - np.pi / 2
    assert tilt == pytest.approx(np.radians(0.1) * np.sin(np.radians(39.1)), rel=0.02)


def _pymap3d_north_angle(frame, lat, lon):
    """The reference: the direction of a small step north, through pymap3d."""
    import pymap3d

    e0, n0, _ = pymap3d.geodetic2enu(lat, lon, frame.alt0, frame.lat0, frame.lon0, frame.alt0)
    e1, n1, _ = pymap3d.geodetic2enu(lat + 1e-5, lon, frame.alt0, frame.lat0, frame.lon0, frame.alt0)
    return np.arctan2(n1 - n0, e1 - e0)


@pytest.mark.parametrize("lat0", [-89.9, -60.0, 0.0, 39.1, 75.0, 89.9])
def test_the_fast_local_frame_equals_pymap3d(lat0):
    """LocalFrame against pymap3d, the reference, for scalars and arrays: to_enu is geodetic2enu's east and north;
    to_geodetic is its inverse at the given altitude (pymap3d's enu2geodetic of the same point, up included), for
    points up to 100 km away and 3 km up, to 1e-6 m and 1e-9 deg (north angle to 1e-6 rad)."""
    import pymap3d

    rng = np.random.default_rng(int(lat0 * 10) % 1000)
    frame = LocalFrame(lat0, float(rng.uniform(-180, 180)), float(rng.uniform(-50, 500)))
    east, north, height = rng.uniform(-1e5, 1e5, 40), rng.uniform(-1e5, 1e5, 40), rng.uniform(-100, 3000, 40)
    lat, lon, alt = frame.to_geodetic(east, north, height)
    assert np.allclose(alt, height, atol=1e-6)
    ref_e, ref_n, ref_u = pymap3d.geodetic2enu(lat, lon, alt, frame.lat0, frame.lon0, frame.alt0)
    assert np.allclose(ref_e, east, atol=1e-6) and np.allclose(ref_n, north, atol=1e-6)
    ref_lat, ref_lon, _ = pymap3d.enu2geodetic(east, north, ref_u, frame.lat0, frame.lon0, frame.alt0)
    assert np.allclose(lat, ref_lat, atol=1e-9)
    assert np.allclose(np.mod(lon - ref_lon + 180, 360) - 180, 0, atol=1e-9)
    e, n = frame.to_enu(lat, lon, alt)
    assert np.allclose(e, ref_e, atol=1e-6) and np.allclose(n, ref_n, atol=1e-6)
    for k in range(5):  # the scalar path (plain floats), point by point
        la, lo, al = frame.to_geodetic(float(east[k]), float(north[k]), float(height[k]))
        assert isinstance(la, float) and la == pytest.approx(ref_lat[k], abs=1e-9) and al == pytest.approx(
            height[k], abs=1e-6)
        ek, nk = frame.to_enu(float(ref_lat[k]), float(ref_lon[k]), float(height[k]))
        assert (ek, nk) == pytest.approx((east[k], north[k]), abs=1e-6)
        if abs(lat0) < 89:  # the probe reference itself is ill-conditioned next to a pole
            assert frame.north_angle(float(ref_lat[k]), float(ref_lon[k])) == pytest.approx(
                float(_pymap3d_north_angle(frame, ref_lat[k], ref_lon[k])), abs=1e-6)
    assert frame.north_angle(lat0, frame.lon0) == pytest.approx(math.pi / 2, abs=1e-12)


@pytest.mark.parametrize("km", [300.0, 3000.0, 5000.0])
def test_a_map_point_far_from_the_datum_goes_down_to_the_ground(km):
    """Far from the datum the plane rises above the ground (7 km at 300 km): a map point is the place on the ground
    below it, so the place goes back to the same map point (the old along-the-plane inverse was 330 m out at 300 km)
    and its distance from the datum is the arc whose sine it is (a sphere's orthographic projection, to 0.5 %)."""
    from pymap3d import vincenty

    frame = LocalFrame(39.1, 117.2, 5.0)
    bearing = np.radians([0.0, 60.0, 135.0, 250.0])
    east, north = km * 1e3 * np.cos(bearing), km * 1e3 * np.sin(bearing)
    lat, lon, alt = frame.to_geodetic(east, north)
    assert np.allclose(alt, 5.0, atol=1e-6)
    e, n = frame.to_enu(lat, lon)
    assert np.max(np.hypot(e - east, n - north)) < 1e-3
    arc = vincenty.vdist(39.1, 117.2, lat, lon)[0]
    assert np.allclose(np.sin(arc / 6.371e6) * 6.371e6, km * 1e3, rtol=5e-3)


def test_a_float_angle_is_wrapped_by_math_to_the_same_bit_as_numpy():
    """The per-reading path wraps plain floats with math; it gives numpy's value exactly (both take the floor
    modulo), at the edges too."""
    rng = np.random.default_rng(1)
    angles = np.r_[rng.uniform(-50, 50, 20000), [math.pi, -math.pi, 0.0, -0.0, 3 * math.pi, 1e-300, -1e-300]]
    scalar = np.array([wrap_pi(float(a)) for a in angles])
    assert isinstance(wrap_pi(1.0), float) and np.array_equal(scalar, wrap_pi(angles))
    az, north = rng.uniform(-400, 400, 20000), rng.uniform(1.5, 1.6, 20000)
    scalar = np.array([azimuth_to_enu(float(a), float(n)) for a, n in zip(az, north, strict=True)])
    assert np.array_equal(scalar, azimuth_to_enu(az, north))


def enu_to_azimuth(theta, north_angle=np.pi / 2):
    """ENU angle (rad, CCW from east) to a DF azimuth in [0, 360) degrees."""
    return wrap_360(np.degrees(north_angle - np.asarray(theta)))
