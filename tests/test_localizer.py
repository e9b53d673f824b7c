"""The Localizer's handling of real-vehicle data: pairing with GPS, and every kind of bad input."""
import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import DATUM, open_point, track_of

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.track.state import TrackState
from aoa_localizer.engine.types import BearingPoseInput, FixInput, Input
from aoa_localizer.simulation.scenarios import SCENARIOS, simulate

FRAME = LocalFrame(*DATUM)
EMITTER = (1200.0, 800.0)


def fix_at(east, north):
    lat, lon, _ = FRAME.to_geodetic(east, north)
    return float(lat), float(lon)


def azimuth(east, north):
    return math.degrees(math.atan2(EMITTER[0] - east, EMITTER[1] - north)) % 360


def drive(loc, seconds=120, speed=10.0, df_hz=5, noise_deg=0.5, seed=0, track=lambda t: (10.0 * t, 0.3 * 10.0 * t),
          t0=0.0):
    """A vehicle on a straight-ish road: 1 Hz fixes, DF readings in between, stamps from t0; the last estimate."""
    rng = np.random.default_rng(seed)
    est = None
    for k in range(seconds):
        e, n = track(k)
        est = loc.add_fix(t0 + k, *fix_at(e, n), 5.0) or est
        for j in range(df_hz):
            t = k + (j + 0.5) / df_hz
            e, n = track(t)
            est = loc.add_bearing(t0 + t, azimuth(e, n) + rng.normal(0, noise_deg), 90.0) or est
    est = loc.add_fix(t0 + seconds, *fix_at(*track(seconds)), 5.0) or est  # brackets the last readings
    return loc.flush() or est


def curved(t):
    """A road that turns left after 60 s, so the bearings cross."""
    return (10.0 * t, 0.0) if t < 60 else (600.0 + 7.0 * (t - 60), 7.0 * (t - 60))


@pytest.fixture
def loc():
    return Localizer(LocalizerConfig(seed=4, datum_lat=DATUM[0], datum_lon=DATUM[1], datum_alt=DATUM[2]))


@pytest.mark.slow
def test_localises_a_drive_past_the_emitter(loc):
    est = drive(loc, track=curved)
    assert est is not None and math.hypot(est.east - EMITTER[0], est.north - EMITTER[1]) < 30
    lat, lon = fix_at(est.east, est.north)
    assert est.lat == pytest.approx(lat, abs=1e-7) and est.lon == pytest.approx(lon, abs=1e-7)
    assert est.cov.shape == (2, 2) and np.all(np.linalg.eigvalsh(est.cov) > 0)
    assert sum(loc.view().rejected.values()) == 0
    status = loc.view().track
    assert status.state is TrackState.TRACKING and not status.alarm and status.outlier_share == 0.0
    assert (status.text, status.points_used, status.bearings_used) == ("tracking", est.points_used, est.bearings_used)


def test_bearing_between_fixes_uses_the_interpolated_position(loc):
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_fix(1.0, *fix_at(10.0, 0.0))
    loc.add_bearing(0.5, 45.0, 90.0)
    (reading,) = open_point(loc)
    assert reading.east == pytest.approx(5.0, abs=1e-3) and reading.north == pytest.approx(0.0, abs=1e-3)
    assert reading.theta == pytest.approx(math.radians(45.0), abs=1e-6)


def test_bearing_after_the_newest_fix_waits_for_the_next_one(loc):
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_bearing(0.5, 45.0, 90.0)
    assert len(loc._intake.stations[""].pending) == 1 and not open_point(loc)
    loc.add_fix(1.0, *fix_at(10.0, 0.0))
    assert not loc._intake.stations[""].pending and open_point(loc)[0].east == pytest.approx(5.0, abs=1e-3)


def test_bearing_in_a_gps_gap_is_dropped_not_paired_with_a_stale_fix(loc):
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_bearing(0.5, 45.0, 90.0)  # waits
    loc.add_fix(10.0, *fix_at(100.0, 0.0))  # 10 s later: gap > gps_max_gap_s
    assert loc.view().rejected["gps_gap"] == 1
    loc.add_bearing(13.0, 45.0, 90.0)  # 3 s after the newest fix: no fix can bracket it within 2 s
    assert loc.view().rejected["gps_gap"] == 2 and not open_point(loc)


def test_bearings_before_any_fix_and_left_waiting_at_the_end_are_counted(loc):
    loc.add_bearing(0.0, 45.0, 90.0)
    assert loc.view().rejected["before_first_fix"] == 1
    loc.add_fix(1.0, *fix_at(0.0, 0.0))
    loc.add_bearing(1.5, 45.0, 90.0)
    loc.flush()
    assert loc.view().rejected["no_fix_after"] == 1


@pytest.mark.parametrize("args, reason", [
    ((1.0, float("nan"), 90.0), "bad_azimuth"),
    ((1.0, float("inf"), 90.0), "bad_azimuth"),
    ((1.0, "north", 90.0), "bad_azimuth"),
    ((float("nan"), 10.0, 90.0), "bad_stamp"),
    ((1.0, 10.0, 150.0), "bad_quality"),
    ((1.0, 10.0, -1.0), "bad_quality"),
    ((1.0, 10.0, 39.9), "low_quality"),
])
def test_bad_bearings_are_rejected_with_a_reason(loc, args, reason):
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_fix(2.0, *fix_at(0.0, 0.0))
    assert loc.add_bearing(*args) is None
    assert loc.view().rejected == {reason: 1}
    assert not loc._intake.stations[""].pending and not open_point(loc)


def test_unknown_quality_is_used_but_counted(loc):
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_fix(2.0, *fix_at(0.0, 0.0))
    loc.add_bearing(1.0, 10.0, float("nan"))
    assert loc.view().unknown_quality == 1 and len(open_point(loc)) == 1


def test_a_readings_own_sigma_overrides_its_qualitys_and_a_pose_is_one_with_it(loc):
    """sigma_deg (a hand-held bearing's, a pose's) is the reading's sigma; NaN or None: its quality's; 0, negative,
    infinite or not a number: refused. add_bearing_enu is add_bearing with the yaw as an azimuth and the variance
    as that sigma."""
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_fix(5.0, *fix_at(0.0, 0.0))
    loc.add_bearing(1.0, 10.0, 90.0, sigma_deg=4.0)
    loc.add_bearing(2.0, 10.0, 90.0, sigma_deg=None)
    loc.add_bearing(3.0, 10.0, 90.0)
    for bad in (0.0, -1.0, math.inf, "wide"):
        loc.add_bearing(3.5, 10.0, 90.0, sigma_deg=bad)
    assert loc.view().rejected == {"bad_sigma": 4}
    sigmas = [math.degrees(r.sigma) for r in open_point(loc)]
    assert sigmas[0] == pytest.approx(4.0) and sigmas[1] == sigmas[2] != pytest.approx(4.0) and len(sigmas) == 3
    feed_pose(loc, 4.0, math.radians(80.0), math.radians(2.0) ** 2)  # unknown quality: a point of its own
    pose = open_point(loc)[-1]
    assert math.degrees(pose.sigma) == pytest.approx(2.0) and pose.stamp == 4.0
    assert math.degrees(pose.theta) == pytest.approx(80.0) and loc.view().unknown_quality == 1
    feed_pose(loc, 4.5, math.radians(80.0), 0.0)  # a pose's variance not filled in: its quality's (none)
    assert dict(loc.view().rejected) == {"bad_sigma": 4}
    feed_pose(loc, 4.6, math.radians(80.0), -1.0)  # negative, as add_bearing's sigma: refused
    feed_pose(loc, 4.7, math.radians(80.0), math.inf)
    assert dict(loc.view().rejected) == {"bad_sigma": 6}


@pytest.mark.parametrize("sigma", [1e-6, 1e-7, 1e-9, 200.0])
def test_a_sigma_no_bearing_has_is_refused_and_fixed_stations_at_the_finest_one_are_located(sigma):
    """Issue 64, item 11: sigma_deg 1e-6 from fixed stations ended finish() in `LinAlgError: Singular matrix`, 1e-7
    to 1e-9 in internal errors and no estimate. Outside [0.001, 180] deg: `bad_sigma`; at 0.001 deg a fix."""
    from aoa_localizer.engine.geodesy import LocalFrame

    frame = LocalFrame(47.0, 8.0, 0.0)
    places = {"a": (0.0, 0.0), "b": (600.0, 0.0), "c": (0.0, 800.0), "d": (600.0, 800.0)}
    for s, expect in ((sigma, None), (1e-3, "tracking")):
        loc = Localizer(LocalizerConfig(seed=1))
        for name, (e, n) in places.items():
            loc.add_station(name, fixed=True, position=(*frame.to_geodetic(e, n)[:2],))
        for k in range(20):
            name = "abcd"[k % 4]
            e, n = places[name]
            lat, lon, _ = frame.to_geodetic(e, n)
            azimuth = float(frame.north_angle(lat, lon))  # the true azimuth at the station, meridians turned
            azimuth = math.degrees(azimuth - math.atan2(400.0 - n, 300.0 - e))
            loc.add_bearing(float(k + 1), azimuth % 360.0, 80.0, station=name, sigma_deg=s)
        loc.flush()
        loc.finish()
        est = loc.view().estimate
        if expect is None:
            assert est is None and dict(loc.view().rejected) == {"bad_sigma": 20}
        else:
            assert est is not None and est.state.value == expect and "internal_error" not in loc.view().rejected
            assert math.hypot(est.east - 300.0, est.north - 400.0) < 0.1
        loc.close()


def test_bearing_stamps_going_backwards_or_repeating_are_rejected(loc):
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_fix(2.0, *fix_at(0.0, 0.0))
    loc.add_bearing(1.0, 10.0, 90.0)
    loc.add_bearing(1.0, 10.0, 90.0)
    loc.add_bearing(0.5, 10.0, 90.0)
    assert loc.view().rejected == {"bearing_repeated": 1, "bearing_out_of_order": 1}


@pytest.mark.parametrize("args, reason", [
    ((1.0, float("nan"), 117.2), "fix_bad_position"),
    ((1.0, 39.1, float("inf")), "fix_bad_position"),
    ((1.0, 91.0, 117.2), "fix_bad_position"),
    ((float("inf"), 39.1, 117.2), "fix_bad_stamp"),
])
def test_bad_fixes_are_rejected(loc, args, reason):
    loc.add_fix(*args)
    assert loc.view().rejected == {reason: 1} and not loc.view().stations


def test_fix_without_a_fix_and_fixes_out_of_order_are_rejected(loc):
    loc.add_fix(5.0, 39.1, 117.2, 5.0, status=-1)
    loc.add_fix(5.0, 39.1, 117.2)
    loc.add_fix(5.0, 39.1, 117.2)
    loc.add_fix(4.0, 39.1, 117.2)
    assert loc.view().rejected == {"fix_no_fix": 1, "fix_repeated": 1, "fix_out_of_order": 1}
    assert len(loc._intake.stations[""].gps) == 1


def test_datum_comes_from_the_first_valid_fix_when_unset():
    loc = Localizer(LocalizerConfig())
    loc.add_fix(0.0, float("nan"), 0.0)
    loc.add_fix(1.0, -33.9, -70.6, 520.0)
    assert loc.view().frame is None and "confirm the datum" in loc.view().status  # one fix alone never sets the datum
    loc.add_fix(2.0, -33.90001, -70.6, 521.0)  # 1 m away a second later: confirms it
    assert (loc.view().frame.lat0, loc.view().frame.lon0, loc.view().frame.alt0) == (-33.9, -70.6, 520.0)


@pytest.mark.slow
def test_driving_straight_at_the_emitter_never_starts_from_a_garbage_fix(loc):
    est = drive(loc, seconds=60, track=lambda t: (10.0 * t * 0.832, 10.0 * t * 0.5547))  # along the emitter's bearing
    assert est is None and loc.view().track.state is not TrackState.TRACKING
    assert "waiting for geometry" in loc.view().status and "parallel" in loc.view().status


@pytest.mark.slow
def test_a_fixed_seed_reproduces_a_run_and_another_seed_does_not():
    runs = []
    for seed in (7, 7, 8):
        loc = Localizer(LocalizerConfig(seed=seed))
        runs.append(drive(loc, seconds=90, track=curved, seed=1))
    assert runs[0].east == runs[1].east and runs[0].north == runs[1].north
    assert runs[0].east != runs[2].east


@pytest.mark.slow
def test_reset_drops_the_track_but_keeps_datum_and_counters(loc):
    drive(loc, seconds=90, track=curved)
    loc.add_bearing(-5.0, 10.0, 10.0)
    frame = loc.view().frame
    loc.reset()
    assert loc.view().track.state is TrackState.COLLECTING and not loc.view().stations and loc.view().estimate is None
    assert loc.view().frame == frame and loc.view().rejected["low_quality"] == 1
    assert drive(loc, seconds=90, track=curved) is not None


@pytest.mark.slow
def test_garbage_never_raises():
    loc = Localizer(LocalizerConfig(seed=1))
    rng = np.random.default_rng(0)
    values = [float("nan"), float("inf"), -float("inf"), None, "x", 1e300, -1e300, 0.0, 45.0, 100.0]
    for k in range(2000):
        if rng.random() < 0.3:
            loc.add_fix(rng.choice(values[:8]) if rng.random() < 0.2 else k * 0.1,
                        *(rng.choice(values) if rng.random() < 0.2 else v for v in fix_at(k, 0.5 * k)))
        else:
            loc.add_bearing(*(rng.choice(values) if rng.random() < 0.3 else v
                              for v in (k * 0.1, azimuth(k, 0.5 * k), 80.0)))
    loc.flush()
    assert sum(loc.view().rejected.values()) > 0


def test_pose_encoding_bearing_is_a_yaw_from_east_with_its_own_variance(loc):
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_fix(1.0, *fix_at(0.0, 0.0))
    feed_pose(loc, 0.5, math.radians(30.0), math.radians(2.0) ** 2)
    (reading,) = open_point(loc)
    assert reading.theta == pytest.approx(math.radians(30.0), abs=1e-6)
    assert reading.sigma == pytest.approx(math.radians(2.0))
    assert loc.view().unknown_quality == 1
    feed_pose(loc, 0.6, float("nan"))
    assert loc.view().rejected == {"bad_azimuth": 1}


def test_a_later_fix_closes_the_open_point_so_a_stopped_vehicle_gets_its_estimate():
    loc = Localizer(LocalizerConfig(seed=2, init_bearings=3, prior_east=EMITTER[0], prior_north=EMITTER[1],
                                    prior_sigma_m=200.0, datum_lat=DATUM[0], datum_lon=DATUM[1], datum_alt=DATUM[2]))
    loc.add_fix(0.0, *fix_at(0.0, 0.0))
    loc.add_fix(1.0, *fix_at(0.0, 0.0))
    loc.add_bearing(0.2, azimuth(0.0, 0.0), 90.0)
    loc.add_bearing(0.3, azimuth(0.0, 0.0), 90.0)
    assert loc.add_fix(2.0, *fix_at(0.0, 0.0)) is None  # 1.8 s after the point's first reading: still open
    est = loc.add_fix(3.0, *fix_at(0.0, 0.0))  # 2.8 s > obs_max_duration_s
    assert est is not None and est.points_used == 1 and est.bearings_used == 2


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the infinite particles are the point of the test
def test_a_diverged_filter_is_never_published_and_restarts():
    loc = Localizer(LocalizerConfig(seed=3, datum_lat=DATUM[0], datum_lon=DATUM[1], datum_alt=DATUM[2]))
    drive(loc, seconds=90, track=curved)
    assert loc.view().track.state is TrackState.TRACKING
    published = loc.view().estimate
    track_of(loc).filter.x = np.full_like(track_of(loc).filter.x, np.inf)  # what a run-away move step leaves behind
    est = drive(loc, seconds=100, track=lambda t: curved(t + 90), t0=1000.0)
    assert loc.view().rejected["filter_diverged"] == 1
    assert est is not None and np.isfinite(est.east) and est.stamp > published.stamp


@pytest.mark.slow
def test_on_estimate_sees_every_estimate_whichever_input_made_it_and_estimate_is_the_latest():
    """ROS-package issue: the README suggested estimates come back from add_bearing; with fixes and readings
    interleaved most come back from add_fix. The callback gets them all, in order, and `estimate` is the latest."""
    seen, returned = [], {"fix": [], "bearing": []}
    loc = Localizer(LocalizerConfig(seed=3), on_estimate=seen.append)
    rng = np.random.default_rng(2)
    for k in range(90):
        e, n = curved(k)
        est = loc.add_fix(k, *fix_at(e, n), 5.0)
        returned["fix"] += [est] if est is not None else []
        for j in range(5):
            t = k + (j + 0.5) / 5
            est = loc.add_bearing(t, azimuth(*curved(t)) + rng.normal(0, 0.5), 90.0)
            returned["bearing"] += [est] if est is not None else []
        assert loc.view().estimate is (seen[-1] if seen else None)
    assert len(returned["fix"]) > len(returned["bearing"])  # the usual case the README now states
    assert {id(e) for e in seen} == {id(e) for e in returned["fix"] + returned["bearing"]}
    assert [e.stamp for e in seen] == sorted(e.stamp for e in seen)
    last = loc.finish()
    assert last is None or seen[-1] is last


@pytest.mark.slow
def test_an_estimates_arrays_are_the_users_own():
    """The filter's cloud and its summary are read-only and shared; an Estimate hands out copies the user may
    change without touching the filter."""
    data = simulate("seed", 1)
    loc = Localizer(LocalizerConfig(seed=3))
    est = next(filter(None, map(loc.feed, data.inputs())))
    cov_before = track_of(loc).filter.estimate()[1].copy()
    est.cov[0, 0] += 1.0
    est.weights[:] = 0.0
    est.particles[:] = 0.0
    f = track_of(loc).filter
    assert np.array_equal(f.estimate()[1], cov_before) and f.weights.sum() == pytest.approx(1.0)
    assert np.any(f.x != 0.0)


@pytest.mark.slow
def test_run_feeds_a_source_and_ends_the_data_as_the_add_calls_flush_and_finish_do():
    """Localizer.run(source): the offline call. Inputs of other kinds (a bag's truth) are passed over; the estimates
    are those the add_ calls, flush() and finish() return, in order."""
    data = simulate(dataclasses.replace(SCENARIOS["seed"], points=24, readings_per_point=2), 3)
    by_hand = Localizer(LocalizerConfig(seed=3))
    made = [by_hand.add_fix(*row[:4]) if kind == "fix" else by_hand.add_bearing(*row[:3])
            for kind, row in data.events()]
    made += [by_hand.flush(), by_hand.finish()]
    expected = [e for e in made if e is not None]
    ran = list(Localizer(LocalizerConfig(seed=3)).run([Input("truth", None), *data.inputs()]))
    assert len(ran) == len(expected) > 10 and ran[-1].end_of_data == expected[-1].end_of_data
    for got, want in zip(ran, expected, strict=True):
        assert (got.stamp, got.east, got.north) == (want.stamp, want.east, want.north)
        assert got.points_used == want.points_used and np.array_equal(got.cov, want.cov)


def test_feed_takes_records_by_field_name_with_optional_fields_left_out_and_names_a_missing_one():
    loc = Localizer(LocalizerConfig(seed=3))
    assert loc.feed(Input("fix", SimpleNamespace(stamp=1.0, lat=DATUM[0], lon=DATUM[1]))) is None
    assert loc.feed(Input("bearing", SimpleNamespace(stamp=1.0, azimuth_deg=45.0))) is None
    assert loc.feed(Input("datum", None)) is None  # a bag's kind, not an input of the engine
    with pytest.raises(TypeError, match="fix input's record has no lat, lon"):
        loc.feed(Input("fix", SimpleNamespace(stamp=2.0)))
    assert loc.feed(Input("bearing", SimpleNamespace(stamp=float("nan"), azimuth_deg="x"))) is None
    assert loc.view().rejected["bad_stamp"] == 1
    loc.feed(Input("fix", FixInput(2.0, DATUM[0], DATUM[1])))  # the fix after the bearing pairs it
    (reading,) = open_point(loc)
    assert math.isnan(reading.quality) and reading.stamp == 1.0


@pytest.mark.slow
def test_calls_from_two_threads_are_made_one_at_a_time():
    """Issue 51, item 10: two threads feeding one Localizer broke its state (internal_error, 2-23 a run). A call
    waits while another thread's is being made, and then is made whole."""
    import threading

    loc = Localizer(LocalizerConfig(datum_lat=39.1, datum_lon=117.2))
    done = threading.Event()

    def feed():
        loc.add_fix(1.0, 39.1, 117.2)
        loc.add_bearing(1.5, 40.0, 90.0)
        done.set()

    with loc._lock:  # another thread's call in progress
        other = threading.Thread(target=feed)
        other.start()
        assert not done.wait(0.3)  # it waits
    other.join(5.0)
    assert done.is_set() and not loc.view().rejected["internal_error"]


@pytest.mark.parametrize("how", ["pickle", "copy", "deepcopy"])
def test_a_localizer_is_neither_pickled_nor_copied_and_says_so(how):
    """Issue 51, item 14: pickling or copying a Localizer failed on an RLock; it now says what it is and what to do."""
    import copy
    import pickle

    loc = Localizer()
    try:
        act = {"pickle": pickle.dumps, "copy": copy.copy, "deepcopy": copy.deepcopy}[how]
        with pytest.raises(TypeError, match="a Localizer cannot be pickled or copied"):
            act(loc)
    finally:
        loc.close()


def feed_pose(loc: Localizer, *fields):
    """A bearing as a pose gives it (stamp, yaw_rad, variance_rad2), fed as an input of kind bearing_pose."""
    return loc.feed(Input("bearing_pose", BearingPoseInput(*fields)))


def _fixed_sites(loc):
    """Four fixed sites around (300, 400) m, five readings each of 1 deg."""
    from aoa_localizer.engine.geodesy import LocalFrame

    frame, rng = LocalFrame(47.0, 8.0, 0.0), np.random.default_rng(2)
    places = {"a": (0.0, 0.0), "b": (600.0, 0.0), "c": (0.0, 800.0), "d": (600.0, 800.0)}
    for name, (e, n) in places.items():
        loc.add_station(name, fixed=True, position=(*frame.to_geodetic(e, n)[:2],))
    for k in range(20):
        name = "abcd"[k % 4]
        e, n = places[name]
        lat, lon, _ = frame.to_geodetic(e, n)
        azimuth = math.degrees(float(frame.north_angle(lat, lon)) - math.atan2(400.0 - n, 300.0 - e))
        loc.add_bearing(float(k + 1), (azimuth + rng.normal(0.0, 1.0)) % 360.0, 80.0, station=name, sigma_deg=1.0)
    loc.flush()
    loc.finish()
    return loc.view().estimate


@pytest.mark.slow
def test_the_survey_model_is_handed_to_the_localizer_not_installed_by_an_import():
    """Issue 65, item 5: the survey solver was installed into the engine when aoa_localizer/__init__ ran. Now a
    Localizer is handed one (default: aoa_localizer.pooled's); a solver of one's own is called with the survey's
    records; None: no survey model, and fixed sites' channels keep their filter's estimate."""
    from aoa_localizer.engine.survey.survey_solver import pooled_solver

    calls = []

    def mine(records, receiver_class, max_k):
        calls.append((len(records), receiver_class, max_k))
        return pooled_solver(records, receiver_class, max_k)

    est = _fixed_sites(Localizer(LocalizerConfig(seed=1), survey_solver=mine))
    assert calls and calls[-1][1:] == ("unknown", 3) and est.algorithm == "survey"
    assert math.hypot(est.east - 300.0, est.north - 400.0) < 20.0
    est = _fixed_sites(Localizer(LocalizerConfig(seed=1), survey_solver=None))
    assert est is not None and est.algorithm != "survey" and math.hypot(est.east - 300.0, est.north - 400.0) < 20.0


def test_a_points_step_returns_what_the_track_says_and_the_estimate_is_made_of_that_value(monkeypatch):
    """Architecture IV: the track's step returns one value (track/said.py) and the estimate is formatted from it
    alone: each published estimate carries the stamp, counts, modes, cloud and noise of the value its point's
    step returned; a value whose covariance is not positive definite is refused, counted, and nothing published."""
    from aoa_localizer.engine.outputs.estimates import Estimates
    from aoa_localizer.engine.track.said import Standing

    pairs = []
    publish = Estimates.publish

    def watched(self, channel, said=None, end_of_data=False):
        made = publish(self, channel, said, end_of_data)
        if said is not None and made is not None:
            pairs.append((said, made))
        return made

    monkeypatch.setattr(Estimates, "publish", watched)
    data = simulate("seed", 1)
    list(Localizer(LocalizerConfig(seed=1)).run(data.inputs()))
    assert len(pairs) > 20 and all(isinstance(s, Standing) for s, _ in pairs)
    for said, est in pairs:
        assert (est.stamp, est.points_used, est.bearings_used, est.ess) == (
            said.stamp, said.points_used, said.bearings_used, said.ess)
        assert est.modes == said.modes and est.noise == said.noise and est.particles is said.particles
    loc = Localizer(LocalizerConfig(seed=1))
    loc.add_fix(1.0, *DATUM[:2])
    loc.add_fix(2.0, *DATUM[:2])
    said = dataclasses.replace(pairs[-1][0], cov=np.zeros((2, 2)), degenerate=True)
    channel = loc._estimates.latest
    assert loc._estimates.publish(channel, said) is None and loc.view().rejected == {"covariance_degenerate": 1}
