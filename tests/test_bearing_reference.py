"""Bearings measured from true north, from magnetic north, or from the vehicle's forward axis (with the array's
mount offset and the heading from the GPS course or an IMU): the same emitter, the same accuracy."""
import dataclasses
import math

import numpy as np
import pytest
from conftest import DATUM

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.ingest.gps_track import GpsTrack
from aoa_localizer.engine.ingest.heading import TrackHeading, _Jitter
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import SCENARIOS, Trajectory, mounted, simulate

FRAME = LocalFrame(*DATUM)
# urban's track (the seed polyline, three corners) driven at 10 m/s, without GPS noise or wild readings
DRIVE = dataclasses.replace(SCENARIOS["urban"], name="drive", gps_noise_m=0.0, wild_share=0.0)
MOUNT = 30.0


def _cfg(**changes):
    return LocalizerConfig(seed=5).with_changes(**changes)


@pytest.mark.slow
def test_relative_bearings_on_a_curved_track_give_the_accuracy_of_true_ones():
    true_err, rel_err = [], []
    for r in range(3):
        true_err.append(run(simulate(DRIVE, r), _cfg()).scores["error"])
        res = run(simulate(mounted(DRIVE, MOUNT), r), _cfg(bearing_reference="vehicle", mount_offset_deg=MOUNT))
        rel_err.append(res.scores["error"])
        # only the readings (10 Hz) of the first 4 s, before the fixes' jitter is known (GPS at 1 Hz)
        assert res.localizer.view().rejected["heading_unknown"] <= 40
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    assert rms(rel_err) < 1.5 * rms(true_err) + 0.5, (true_err, rel_err)


def _watched(cfg: LocalizerConfig) -> tuple[Localizer, list]:
    """A Localizer on `cfg` and the readings it pairs into observation points, as it makes them."""
    readings: list = []
    observer = type("Obs", (), {"on_fix": lambda *a: None, "on_point": lambda self, rs, kept: readings.extend(rs)})()
    return Localizer(cfg, observer=observer), readings


def _drive_east(loc, az_of, speed=10.0, seconds=20, stop_after=None):
    """A vehicle driving east from the datum (stopping at `stop_after` s): 1 Hz fixes, a reading at each
    half second, azimuth az_of(t, east)."""
    for k in range(seconds + 1):
        east = speed * min(k, stop_after if stop_after is not None else k)
        lat, lon, _ = FRAME.to_geodetic(east, 0.0)
        loc.add_fix(float(k), float(lat), float(lon), 5.0)
        t = k + 0.5
        loc.add_bearing(t, az_of(t, speed * min(t, stop_after if stop_after is not None else t)), 90.0)


def test_a_relative_bearing_is_turned_by_the_heading_and_the_mount_by_hand():
    """Driving east (heading 90 deg), an array mounted 30 deg right of the nose reading 60 deg: true azimuth 180,
    so the reading points due south, ENU angle -90 deg."""
    loc, readings = _watched(_cfg(bearing_reference="vehicle", mount_offset_deg=30.0, datum_lat=DATUM[0],
                                  datum_lon=DATUM[1], datum_alt=DATUM[2]))
    _drive_east(loc, lambda t, e: 60.0, seconds=8)
    loc.flush()
    assert readings and all(r.theta == pytest.approx(-math.pi / 2, abs=1e-3) for r in readings)


def test_magnetic_azimuths_are_turned_by_the_declination():
    loc, readings = _watched(_cfg(bearing_reference="magnetic_north", magnetic_declination_deg=-7.0,
                                  datum_lat=DATUM[0], datum_lon=DATUM[1], datum_alt=DATUM[2]))
    _drive_east(loc, lambda t, e: 97.0, seconds=6)  # magnetic 97 = true 90: due east
    loc.flush()
    assert readings and all(r.theta == pytest.approx(0.0, abs=1e-3) for r in readings)


def test_a_stopped_vehicle_holds_its_heading_then_refuses_with_a_reason():
    cfg = _cfg(bearing_reference="vehicle", heading_hold_s=5.0, datum_lat=DATUM[0], datum_lon=DATUM[1],
               datum_alt=DATUM[2])
    loc, readings = _watched(cfg)
    _drive_east(loc, lambda t, e: 0.0, seconds=20, stop_after=6)  # stops at 6 s, readings until 20.5 s
    loc.flush()
    # A reading is paired once the fixes reach 3 s (heading_window_s) past it; no course is trusted before the
    # fixes' jitter is known (a sample at each fix from the third on, four needed: the fix at 5 s), so the reading at
    # 0.5 s (paired at the fix at 4 s) is refused. A course over the window before each fix is still good at the fix
    # at 8 s (widened to 6 s): that heading is held up to 13 s, so the readings at 13.5 ... 19.5 s (7) are refused
    # too; the one at 20.5 s has no fix after it.
    assert loc.view().rejected["heading_unknown"] == 8
    assert len(readings) + loc.view().rejected["heading_unknown"] + loc.view().rejected["no_fix_after"] == 21
    assert all(r.theta == pytest.approx(0.0, abs=1e-3) for r in readings)  # straight ahead of an east-bound car


def test_the_fit_and_the_jitter_look_across_the_track_by_hand():
    """Fixes (0, 0), (5, 1), (10, 0) at 0, 1, 2 s: the middle one lies 1 m across the chord, whose variance for
    white noise is 1 + 1/4 + 1/4 = 1.5 fix variances; a speed change along a straight line is no jitter. The fit's
    velocity is (5, 0) m/s, and its one residual degree of freedom holds the 2/3 m^2 across the track."""
    track = GpsTrack(max_gap_s=5.0)
    for t, e, n in ((0.0, 0.0, 0.0), (1.0, 5.0, 1.0), (2.0, 10.0, 0.0)):
        track.add(t, e, n, math.pi / 2)
    assert track.line_residual() == pytest.approx((1.0, 1.5))
    fit = track.fitted_motion(0.0, 2.0)
    assert (fit.v_east, fit.v_north, fit.sxx, fit.dof) == pytest.approx((5.0, 0.0, 2.0, 1))
    assert fit.rss_across == pytest.approx(2.0 / 3.0)  # residuals -1/3, 2/3, -1/3 in north
    braking = GpsTrack(max_gap_s=5.0)
    for t, e in ((0.0, 0.0), (1.0, 9.0), (2.0, 10.0)):
        braking.add(t, e, 0.0, math.pi / 2)
    assert braking.line_residual() == (0.0, 1.5)


def test_the_fixes_jitter_is_an_upper_bound_that_a_turn_does_not_lift():
    """White noise of 2 m (variance 4 m^2) on a straight drive: nothing before 4 samples, then a 95 % upper bound,
    wide with few samples and near 4 m^2 over 256; a 90 deg turn's few large samples barely move it."""
    jitter = _Jitter()
    rng = np.random.default_rng(2)
    track = GpsTrack(max_gap_s=5.0)
    bounds = []
    for k in range(300):
        track.add(float(k), 10.0 * k + 2.0 * rng.standard_normal(), 2.0 * rng.standard_normal(), math.pi / 2)
        jitter.add(track.line_residual())
        bounds.append(jitter.variance)
    assert bounds[:5] == [None] * 5  # samples from the third fix on: the fourth comes with the sixth fix
    assert np.mean(np.array(bounds[5:]) < 4.0) < 0.15  # a 95 % bound: below the truth about one time in twenty
    assert bounds[8] > 2.0 * bounds[-1] and 3.0 < bounds[-1] < 8.0
    straight = jitter.variance
    for k in range(1, 4):  # turned north at the last fix
        track.add(299.0 + k, 2990.0 + 2.0 * rng.standard_normal(), 10.0 * k + 2.0 * rng.standard_normal(), math.pi / 2)
        jitter.add(track.line_residual())
    assert abs(jitter.variance / straight - 1.0) < 0.1


def test_a_smooth_gps_drift_the_jitter_cannot_see_is_inside_the_courses_sigma():
    """A receiver's smoothed position error (1 m, swinging over a minute: up to 0.1 m/s) with 5 cm of jitter, on a
    car at 2 m/s: the jitter alone would give a sigma of a fraction of a degree for errors of up to 3 deg; the
    drift term (0.1 m/s) covers them."""
    z = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        track, heading = GpsTrack(max_gap_s=5.0), TrackHeading(_cfg())
        phase = rng.uniform(0.0, 2.0 * math.pi, 2)
        for k in range(300):
            t = k + 0.37
            drift = np.sin(2.0 * math.pi * t / 60.0 + phase)
            place = np.array([2.0 * t, 0.0]) + drift + 0.05 * rng.standard_normal(2)
            track.add(t, place[0], place[1], math.pi / 2)
            heading.note_fix(track)
            if k > 20:  # a reading 5 s back: the fixes after it are there
                course = heading.at(track, k - 4.5, 0.0, None)
                if course is not None:
                    z.append(math.remainder(course[0], 2.0 * math.pi) / course[1])
    assert len(z) > 1000 and np.sqrt(np.mean(np.square(z))) < 1.2 and np.max(np.abs(z)) < 3.5


def test_a_stopped_vehicle_on_noisy_gps_keeps_the_course_it_came_with_and_its_sigma_covers_the_error():
    """3 m of white noise on 1 Hz fixes: stopped, they look like 2-3 m/s in random directions, which the speed gate
    alone took for a course. Weighed against the fixes' jitter, the course is the one the vehicle arrived with
    (east) and each reading carries a heading sigma that covers its error (6 runs, 30 s driving then 30 s stopped)."""
    z, stopped_err = [], []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        # the readings only: no filter starts
        loc, readings = _watched(_cfg(bearing_reference="vehicle", datum_lat=DATUM[0], datum_lon=DATUM[1],
                                      datum_alt=DATUM[2], init_bearings=1000, init_max_points=1000))
        for k in range(61):
            noise = 3.0 * rng.standard_normal(2)
            lat, lon, _ = FRAME.to_geodetic(10.0 * min(k, 30) + noise[0], noise[1])
            loc.add_fix(float(k), float(lat), float(lon), 5.0)
            loc.add_bearing(k + 0.5, 0.0, 90.0)  # straight ahead
        loc.flush()
        assert len(readings) >= 50  # a few early ones wait for the jitter, one has no fix after it
        z += [r.theta / r.heading_sigma for r in readings]
        stopped_err += [abs(r.theta) for r in readings if r.stamp > 33.0]
    assert len(stopped_err) >= 6 * 27 - 6 and max(stopped_err) < math.radians(25.0)
    z = np.array(z)
    assert 0.3 < np.sqrt(np.mean(z**2)) < 1.5 and np.mean(np.abs(z) > 3.0) < 0.02


@pytest.mark.slow
def test_a_mounted_array_on_noisy_gps_stays_near_the_emitter_inside_its_ellipse():
    """The `seed` drive (stop-and-go) with its array mounted at 30 deg and 3 m of GPS noise: the course's sigma
    widens the bearings, so the estimate stays within tens of metres (it was hundreds to thousands off with a
    course taken from the noise at each stop) and its ellipse holds the truth."""
    sc = dataclasses.replace(mounted(SCENARIOS["seed"], MOUNT), gps_noise_m=3.0)
    for seed in (1, 2):
        res = run(simulate(sc, seed), _cfg(bearing_reference="vehicle", mount_offset_deg=MOUNT))
        assert res.scores["error"] < 40.0 and res.scores["inside95"], res.scores["error"]


def test_an_imu_heading_is_interpolated_at_the_reading_and_bad_ones_are_counted():
    cfg = _cfg(bearing_reference="vehicle", heading_source="imu", datum_lat=DATUM[0], datum_lon=DATUM[1],
               datum_alt=DATUM[2])
    loc, readings = _watched(cfg)
    for k in range(41):  # yaw turning from 0 (east) to pi/2 (north) over 20 s, 2 Hz
        loc.add_heading(0.5 * k, math.pi / 2 * min(0.5 * k / 20.0, 1.0))
    loc.add_heading(3.0, 0.0)  # out of order
    loc.add_heading(30.0, float("nan"))
    for k in range(21):
        lat, lon, _ = FRAME.to_geodetic(0.0, 0.0)
        loc.add_fix(float(k), float(lat), float(lon), 5.0)
        loc.add_bearing(k + 0.25, 0.0, 90.0)  # straight ahead
    loc.flush()
    expected = [math.pi / 2 * (r.stamp / 20.0) for r in readings]
    assert readings and np.allclose([r.theta for r in readings], expected, atol=2e-3)
    assert loc.view().rejected["heading_out_of_order"] == 1 and loc.view().rejected["bad_heading"] == 1
    true_north = Localizer(_cfg())
    true_north.add_heading(1.0, 0.0)
    assert true_north.view().rejected["heading_ignored"] == 1  # never silently used


def test_an_imu_message_gives_its_yaw_and_an_unknown_orientation_is_nan():
    from msgs_adapters.build import header, rclpy_types
    from msgs_adapters.fields import heading_from_imu

    T = rclpy_types()
    yaw = 0.7
    msg = T.Imu(header=header(T, 12.5, "imu"))
    msg.orientation.z, msg.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    r = heading_from_imu(msg)
    assert r.stamp == 12.5 and r.yaw_rad == pytest.approx(yaw)
    assert math.isnan(r.variance_rad2)  # a covariance of zeros: not known (REP-145)
    msg.orientation_covariance[8] = 0.0025  # the yaw's variance: (0.05 rad)^2
    assert heading_from_imu(msg).variance_rad2 == 0.0025
    msg.orientation_covariance[0] = -1.0  # REP-145: no orientation estimate
    assert math.isnan(heading_from_imu(msg).yaw_rad) and math.isnan(heading_from_imu(msg).variance_rad2)


def test_an_imu_yaws_variance_is_the_readings_heading_sigma():
    """An IMU's yaw known to 0.05 rad: the readings turned by it carry that heading sigma (the larger of the two
    samples around them); a variance not known (NaN, 0, negative) is taken as exact."""
    for variance, sigma in ((0.0025, 0.05), (float("nan"), 0.0), (0.0, 0.0), (-1.0, 0.0)):
        loc, readings = _watched(_cfg(bearing_reference="vehicle", heading_source="imu", init_bearings=100,
                                      init_max_points=100))
        for k in range(12):
            loc.add_heading(float(k), 0.0, variance_rad2=variance)
            lat, lon, _ = FRAME.to_geodetic(0.0, 0.0)
            loc.add_fix(float(k), float(lat), float(lon), 5.0)
            loc.add_bearing(k + 0.5, 0.0, 90.0)
        loc.flush()
        assert len(readings) == 11 and all(r.heading_sigma == pytest.approx(sigma) for r in readings)


def test_offline_replay_feeds_a_bags_imu_headings_to_the_engine():
    from msgs_adapters.bag import BagEvent
    from msgs_adapters.fields import HeadingRecord

    loc = Localizer(_cfg(bearing_reference="vehicle", heading_source="imu"))
    assert loc.feed(BagEvent("heading", 0, HeadingRecord(1.0, 0.3))) is None
    assert loc.feed(BagEvent("heading", 0, HeadingRecord(0.5, 0.3))) is None
    assert loc._intake.stations[""].heading.samples.t == [1.0] and loc.view().rejected["heading_out_of_order"] == 1


def test_the_simulator_takes_azimuths_from_the_forward_axis_with_its_mount_offset():
    """`Scenario.mount_offset_deg`: the same run's azimuths less the heading (east on `straight`'s road: 90 deg) and
    the mount, to within the meridian convergence over the road (0.02 deg); at a corner the vehicle faces the way
    it came."""
    north, rel = simulate(SCENARIOS["straight"], 4), simulate(mounted(SCENARIOS["straight"], 30.0), 4)
    np.testing.assert_allclose((north.bearings[:, 1] - rel.bearings[:, 1]) % 360.0, 120.0, atol=0.03)
    np.testing.assert_array_equal(rel.fixes, north.fixes)
    corner = Trajectory(((0, 0), (100, 0), (100, 100)), 10.0)
    np.testing.assert_allclose(corner.course([0.0, 5.0, 10.0, 15.0]), [0.0, 0.0, 0.0, math.pi / 2])


@pytest.mark.slow
def test_simulate_shows_relative_bearings_and_a_wrong_mount_offset_learned(cli):
    """`simulate --mount-offset-deg 30` sets the localizer to read what it records; with `-p mount_offset_deg=0`
    the offset is found, learned and named."""
    from aoa_localizer.tools.simulate import main as simulate_main

    right = cli(simulate_main, "--mount-offset-deg", 30)
    assert right.returncode == 0 and "heading_unknown" in right.stdout, right.stdout + right.stderr
    wrong = cli(simulate_main, "--mount-offset-deg", 30, "-p", "mount_offset_deg=0")
    assert wrong.returncode == 0 and "set mount_offset_deg to 30.0?" in wrong.stdout, wrong.stdout + wrong.stderr
    assert cli(simulate_main, "--mount-offset-deg", "north").returncode == 2
