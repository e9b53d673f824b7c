"""One bad message at the wrong moment never breaks a run: absurd first fixes, bad stamps, clock steps, GPS loss,
degenerate covariances (the reliability issue's findings, each reproduced, then passing)."""
import math
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import track_of

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.ingest.input_guard import StreamClock, Verdict
from aoa_localizer.engine.types import EstimateState
from aoa_localizer.reporting.words import clock_hint_sentence, robustness_lines
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import simulate
from msgs_adapters.fields import stamp_seconds

FUTURE = 2_145_916_800.0  # 2038-01-01


def play(loc, data, shift=0.0):
    """A scenario's stream into `loc`; the estimates it made."""
    out = []
    for kind, row in data.events():
        est = loc.add_fix(row[0] + shift, *row[1:4]) if kind == "fix" else loc.add_bearing(row[0] + shift, *row[1:3])
        if est is not None:
            out.append(est)
    return out


def final_error(loc, data) -> float:
    e, n = data.frame.to_enu(loc.view().estimate.lat, loc.view().estimate.lon)
    return float(math.hypot(e - data.emitter_enu[0], n - data.emitter_enu[1]))


@pytest.mark.slow
@pytest.mark.parametrize("first", [(45.0, 117.2, 1e190), (39.1, 117.2, -1e9), (90.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                                   (10.0, 10.0, 5.0)])
def test_an_absurd_first_fix_neither_crashes_nor_becomes_the_datum(first):
    """Finding 1: 1e190 m altitude used to raise OverflowError for good; a pole or null island used to give
    estimates 1,000 km off with a small ellipse; a sane-looking fix 11,000 km away is contradicted by the next
    one."""
    data = simulate("seed", 0)
    loc = Localizer(LocalizerConfig(seed=1))
    loc.add_fix(data.fixes[0, 0] - 0.5, *first)
    play(loc, data)
    loc.flush()
    assert loc.view().estimate is not None and final_error(loc, data) < 10.0
    assert abs(loc.view().frame.lat0 - 39.1) < 0.1 and abs(loc.view().frame.lon0 - 117.2) < 0.1
    assert sum(loc.view().rejected[r] for r in ("fix_bad_altitude", "fix_near_pole", "fix_null_island",
                                         "fix_unconfirmed")) == 1


def test_reset_can_drop_a_datum_that_was_not_configured():
    loc = Localizer(LocalizerConfig())
    loc.add_fix(0.0, 39.1, 117.2, 5.0)
    loc.add_fix(1.0, 39.1, 117.2, 5.0)
    assert loc.view().frame is not None
    loc.reset()
    assert loc.view().frame is not None  # the map frame stays put by default
    loc.reset(drop_datum=True)
    assert loc.view().frame is None
    configured = Localizer(LocalizerConfig(datum_lat=1.0, datum_lon=2.0))
    configured.reset(drop_datum=True)
    assert configured.view().frame.lat0 == 1.0  # a configured datum is never dropped


@pytest.mark.slow
def test_one_record_and_one_fix_from_2038_do_not_stop_a_whole_scenario():
    """Finding 2: they used to become the streams' "latest", then every good input was out of order (0 of 39
    estimates, status a calm "collecting bearings")."""
    data = simulate("seed", 0)
    loc = Localizer(LocalizerConfig(seed=1))
    loc.add_fix(FUTURE, 39.1, 117.2, 5.0)
    loc.add_bearing(FUTURE, 33.0, 90.0)
    estimates = play(loc, data)
    assert len(estimates) > 30 and final_error(loc, data) < 10.0


@pytest.mark.slow
def test_a_clock_that_steps_back_and_stays_back_is_followed():
    """Finding 2: a DF clock stepping back 10 s used to lose every later bearing (495 of them). Now the step is
    recognised after 3 readings and the stream goes on (bearings 10 s off their GPS pair with the wrong
    positions, and some are dropped as wild: that is a clock error, which a time offset must correct)."""
    data = simulate("seed", 0)
    loc = Localizer(LocalizerConfig(seed=1))
    half = data.bearings[len(data.bearings) // 2, 0]
    for kind, row in data.events():
        if kind == "fix":
            loc.add_fix(*row[:4])
        else:
            loc.add_bearing(row[0] - (10.0 if row[0] > half else 0.0), *row[1:3])
    loc.flush()
    assert loc.view().events["df_clock_jump"] == 1
    assert loc.view().rejected["bearing_out_of_order"] <= 2  # the readings it took to recognise the step
    loc.finish()  # a start search still running (the step may read as an emitter that moved) is made
    track = track_of(loc)
    # was: nothing after the step; now the filter holds the stream up to its last point, on either reading
    assert track.window[-1].point.stamp == pytest.approx(data.bearings[-1, 0] - 10.0, abs=1.0)
    assert loc.view().track.points_used == len(track.window) >= 10


def test_a_single_stamp_far_ahead_is_refused_not_adopted():
    clock = StreamClock(max_jump_s=300.0)
    assert clock.admit(100.0) is Verdict.OK
    assert clock.admit(FUTURE) is Verdict.AHEAD
    assert clock.admit(101.0) is Verdict.OK and clock.last == 101.0
    assert clock.admit(100.5) is Verdict.OUT_OF_ORDER
    assert clock.admit(102.0) is Verdict.OK  # an isolated late record is not a clock step
    for t in (50.0, 51.0):
        assert clock.admit(t) is Verdict.OUT_OF_ORDER
    assert clock.admit(52.0) is Verdict.CLOCK_JUMP and clock.last == 52.0


def test_a_header_nanosec_out_of_range_is_a_bad_stamp():
    header = SimpleNamespace(stamp=SimpleNamespace(sec=100, nanosec=4_294_967_295))
    assert math.isnan(stamp_seconds(header))
    loc = Localizer(LocalizerConfig())
    loc.add_bearing(stamp_seconds(header), 10.0, 90.0)
    assert loc.view().rejected["bad_stamp"] == 1


def test_bearings_waiting_for_a_fix_age_out_when_the_gps_stops():
    """Finding 8: with GPS gone, every bearing used to be queued (720,000 after an hour at 200 Hz)."""
    loc = Localizer(LocalizerConfig(datum_lat=39.1, datum_lon=117.2))
    loc.add_fix(0.0, 39.1, 117.2, 5.0)
    for k in range(20_000):  # 100 s at 200 Hz, no fix
        loc.add_bearing(0.5 + k / 200.0, 45.0, 90.0)
    assert len(loc._intake.stations[""].pending) <= 2 * loc.config.gps_max_gap_s * 200 + 1
    assert loc.view().rejected["gps_gap"] >= 20_000 - len(loc._intake.stations[""].pending)


def test_most_inputs_refused_is_said_in_the_status():
    loc = Localizer(LocalizerConfig(datum_lat=39.1, datum_lon=117.2))
    loc.add_fix(0.0, 39.1, 117.2, 5.0)
    for _k in range(30):
        loc.add_bearing(10.0, float("nan"), 90.0)
    assert "most inputs refused: bad_azimuth" in loc.view().status


@pytest.mark.parametrize("changes", [{"num_particles": 2}, {"num_particles": 10}, {"algorithm": "upf"},
                                     {"algorithm": "upfde", "num_particles": 10}, {"process_noise_m": 0.0}])
@pytest.mark.slow
def test_every_published_covariance_is_positive_definite(changes):
    """Finding 9: valid non-default settings gave 276 non-positive-definite covariances in 1,652 estimates."""
    res = run(simulate("seed", 1), LocalizerConfig(seed=2, **changes))
    for est in res.estimates:
        assert np.all(np.isfinite(est.cov)) and np.all(np.linalg.eigvalsh(est.cov) > 0)
    # Two particles never span a plane: nothing is published, and every refusal is counted.
    assert res.estimates or res.localizer.view().rejected["covariance_degenerate"] > 0


@pytest.mark.slow
def test_fuzzed_first_fixes_and_stamps_never_raise():
    """A bounded fuzz of the first-fix and stamp paths: wild values in every field, then a good scenario."""
    rng = np.random.default_rng(7)
    data = simulate("seed", 2)
    wild = [np.nan, np.inf, -np.inf, 0.0, -0.0, 1e308, -1e308, 1e-308, 90.0, -90.0, 180.0, 1e190, FUTURE, -1.0]
    for _ in range(12):  # each: 1-5 bad fixes and bearings first, then a whole good scenario (bounded: seconds)
        loc = Localizer(LocalizerConfig(seed=3, num_particles=30))
        for _ in range(rng.integers(1, 6)):
            pick = lambda: wild[rng.integers(len(wild))] if rng.random() < 0.7 else rng.normal(0, 1e3)  # noqa: E731
            loc.add_fix(pick(), pick(), pick(), pick())
            loc.add_bearing(pick(), pick(), pick())
        play(loc, data)
        loc.flush()
        assert loc.view().estimate is not None and final_error(loc, data) < 15.0, loc.view().status


@pytest.mark.slow
def test_the_fixes_own_covariance_keeps_the_ellipse_honest_near_the_emitter():
    """Finding 9: passing 10 m from the emitter with 3 m GPS noise, the ellipse used to shrink far below the
    error (the antenna's own position error was ignored). With each NavSatFix's covariance (sigma_m) the 95 %
    ellipse holds the truth in most runs (8 of 8 measured); without it, most runs lie outside their ellipse: the
    median run's NEES is over the 95 % bound (9.9-21 measured over filter seeds and numpy versions; a count of the
    runs inside, 3 or 4 of 8, was too close to call)."""
    from aoa_localizer.simulation.scenarios import Scenario

    sc = Scenario("close", (1200.0, 800.0), ((0.0, 0.0), (1200.0, 790.0), (2400.0, 0.0)), points=40,
                  readings_per_point=3, quality=(90.0, 90.0), gps_noise_m=3.0, dwell_s=3.0)
    values: dict[bool, list[float]] = {True: [], False: []}
    for r in range(8):
        data = simulate(sc, r)
        for with_cov in (True, False):
            loc = Localizer(LocalizerConfig(seed=r))
            for kind, row in data.events():
                if kind == "fix":
                    loc.add_fix(*row[:4], 0, 3.0 if with_cov else float("nan"))
                else:
                    loc.add_bearing(*row[:3])
            loc.flush()
            east, north = loc.view().frame.to_enu(*data.frame.to_geodetic(*data.emitter_enu)[:2])
            err = np.array([loc.view().estimate.east - east, loc.view().estimate.north - north])
            values[with_cov].append(float(err @ np.linalg.solve(loc.view().estimate.cov, err)))
    assert sum(v <= 5.991 for v in values[True]) >= 6 and np.median(values[False]) > 5.991, values


@pytest.mark.slow
def test_a_known_df_clock_offset_is_taken_off():
    """Finding 6: DF stamps 2 s late on `urban` gave 23 m error with a 2.2 m ellipse (22.6 m here, the truth
    outside it, `tracking`, with the motion watch off). With df_time_offset_s the run is back at the baseline
    (t + 2 - 2 is not always t in floating point, so not to the last digit). With the watch on (the default) the
    lag reads as motion (p 0.996): the place is held, not `tracking`, and its ellipse holds the truth."""
    late = simulate("urban", 0)
    late.bearings[:, 0] += 2.0
    off = run(late, LocalizerConfig(seed=1, motion_model="static")).scores
    fixed = run(late, LocalizerConfig(seed=1, df_time_offset_s=-2.0, motion_model="static")).scores
    assert off["error"] > 10.0 and not off["inside95"]
    assert fixed["error"] < 2.0 and fixed["inside95"]
    watched = run(late, LocalizerConfig(seed=1))
    assert watched.scores["inside95"] and watched.estimates[-1].state is not EstimateState.TRACKING


@pytest.mark.slow
@pytest.mark.parametrize("late_s", [0.0, 2.0])
def test_stamps_that_a_clock_offset_explains_are_pointed_out(late_s):
    """Reliability finding 6: a DF clock 2 s off the GPS clock gave 23 m error, status "tracking". The bearings are
    now checked for a stamp shift that fits the track far better; the suggestion lands within 0.5 s of the truth,
    and a run on time gets no suggestion."""
    data = simulate("urban", 0)
    data.bearings[:, 0] += late_s
    loc = Localizer(LocalizerConfig(seed=1))
    play(loc, data)
    loc.flush()
    loc.finish()
    hint = track_of(loc).supervisor.clock_hint
    if late_s == 0.0:
        assert hint is None and clock_hint_sentence(loc) is None
    else:
        assert hint is not None and abs(hint.shift_s + late_s) <= 0.5 and hint.gain >= 10
        assert "try df_time_offset_s = " in clock_hint_sentence(loc)
        assert any("DF stamps shifted" in line for line in robustness_lines(loc))


def test_stamp_gaps_count_a_hole_in_a_regular_stream_and_nothing_else():
    from aoa_localizer.engine.ingest.input_guard import StampGaps

    gaps = StampGaps()
    for k in range(100):
        gaps.add(0.1 * k)
    assert (gaps.gaps, gaps.missing) == (0, 0)
    for k in range(150, 160):  # stamps 10.0-14.9 s never came: 50 missing at 10 Hz
        gaps.add(0.1 * k)
    assert gaps.gaps == 1 and gaps.missing == 50
    gaps.add(10.0)  # a stamp from the past changes nothing
    gaps.add(15.95)  # within 5 intervals: no gap
    assert gaps.gaps == 1


def test_the_closed_form_positive_definite_test_agrees_with_the_eigenvalues():
    """The 2x2 test (low eigenvalue as det / high) against numpy's eigenvalues, over scales from 1e-6 to 1e6 and
    near-singular clouds; non-finite and singular covariances are refused."""
    from aoa_localizer.engine.track.said import positive_definite as _positive_definite

    rng = np.random.default_rng(0)
    for i in range(5000):
        a = rng.standard_normal((2, 2)) * 10 ** rng.uniform(-6, 6)
        cov = a @ a.T if i % 3 else np.outer(a[0], a[0]) + 10 ** rng.uniform(-14, -6) * (a[0] @ a[0]) * np.eye(2)
        low, high = np.linalg.eigvalsh(cov)
        assert _positive_definite(cov) == bool(high > 0 and low > 1e-9 * high)
    assert not any(_positive_definite(np.array(c, float)) for c in ([[0, 0], [0, 0]], [[1, 0], [0, np.nan]],
                                                                     [[1, 1], [1, 1]], [[np.inf, 0], [0, 1]]))


def test_a_normal_runs_refusals_are_not_logged_as_faults(caplog):
    """Issue 53, part 4: a sample bag's normal run printed WARNING lines a user reads as faults. Bearings before the
    first fix, wild readings inside a point and the last bearings without a fix after them are logged at INFO; a
    bad input still warns. Each is counted either way."""
    import logging

    from aoa_localizer.engine.rejections import Reason, Rejections

    rejections = Rejections()
    with caplog.at_level(logging.INFO, logger="aoa_localizer"):
        for reason in (Reason.BEFORE_FIRST_FIX, Reason.POINT_OUTLIER, Reason.NO_FIX_AFTER, Reason.BAD_AZIMUTH):
            rejections(reason)
    levels = {r.getMessage().split(":")[1].split()[0]: r.levelname for r in caplog.records}
    assert levels == {"before_first_fix": "INFO", "point_outlier": "INFO", "no_fix_after": "INFO",
                      "bad_azimuth": "WARNING"}
    assert rejections.counts["point_outlier"] == 1


def test_the_fix_reasons_are_every_reason_a_fix_is_refused_for():
    """/diagnostics counts refused fixes apart from bearings by FIX_REASONS (it summed names by their prefix)."""
    from aoa_localizer.engine.rejections import FIX_REASONS, Reason

    assert FIX_REASONS == {r for r in Reason if r.name.startswith("FIX_")}
    assert "fix_no_fix" in FIX_REASONS and "gps_gap" not in FIX_REASONS  # the counter's plain strings find them
