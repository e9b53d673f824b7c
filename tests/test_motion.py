"""Moving transmitters (engine/inference/motion.py, issue 68): the motion watch's model probability on a standing and
a walking transmitter, its pieces by hand, the posterior Cramer-Rao bound, and what bad input gets."""
import math

import numpy as np
import pytest

from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import crlb_rmse, ou_transition, pcrb_moving
from aoa_localizer.engine.inference.motion import (
    MOVING_P,
    NEVER_MOVES,
    PRIOR_MOVING,
    SWITCH_S,
    UNSURE_P,
    MotionWatch,
    mixture,
    switched,
    weighed,
)
from aoa_localizer.engine.types import Estimate, ObservationPoint
from aoa_localizer.simulation.scenarios import Trajectory, moving_cells, simulate

SIGMA = math.radians(2.0)


def ring_points(transmitter, seconds: float, rng: np.random.Generator, every_s: float = 1.0, per_point: int = 3):
    """A DF vehicle on a 900 m ring around (1000, 1000) at 10 m/s, a reading every `every_s` of the transmitter
    at `transmitter(t)` with 2 deg noise, `per_point` readings to an observation point (their mean bearing, sigma
    over root n, at their mean time and place)."""
    t = np.arange(0.0, seconds, every_s)
    a = 10.0 * t / 900.0
    east, north = 1000.0 + 900.0 * np.cos(a), 1000.0 + 900.0 * np.sin(a)
    place = transmitter(t)
    theta = np.arctan2(place[:, 1] - north, place[:, 0] - east) + SIGMA * rng.standard_normal(t.size)
    return [ObservationPoint(float(t[k:k + per_point].mean()), float(east[k:k + per_point].mean()),
                             float(north[k:k + per_point].mean()), float(theta[k:k + per_point].mean()),
                             SIGMA / math.sqrt(per_point), per_point) for k in range(0, t.size - per_point, per_point)]


def watch_run(transmitter, seconds: float, seed: int):
    """The watch over the points, weighed against a standing transmitter's posterior (a cloud with a 5 m ellipse)
    where the transmitter stood at the start (the channel filter's part in the engine); the probabilities of
    motion and the last Motion."""
    points = ring_points(transmitter, seconds, np.random.default_rng(seed))
    stood = transmitter(np.array([0.0]))[0]
    cloud = stood + 5.0 * np.random.default_rng(seed + 100).standard_normal((500, 2))
    watch = MotionWatch(points[0], 30.0, np.random.default_rng(seed))
    p, motion = [], None
    for point in points[1:]:
        motion = watch.step(point, (cloud, np.full(500, 1 / 500), 25.0 * np.eye(2), 0.0))
        p.append((point.stamp, motion.p_moving))
    return np.array(p), motion


def test_a_standing_transmitter_stays_static_and_a_walker_is_found_moving_within_two_minutes():
    standing = lambda t: np.tile([1000.0, 1000.0], (np.size(t), 1))  # noqa: E731
    walk = Trajectory(((1000.0, 1000.0), (1300.0, 1000.0), (1300.0, 1300.0)), 1.4)
    for seed in (1, 2):
        p, _ = watch_run(standing, 400.0, seed)
        # never published as moving, and rarely undecided (a run of residuals one way now and then)
        assert p[:, 1].max() < MOVING_P and np.mean(p[:, 1] >= UNSURE_P) < 0.05 and p[-1, 1] < UNSURE_P
        p, motion = watch_run(walk.at, 400.0, seed)
        sure = p[p[:, 1] >= 0.9, 0]
        assert sure.size and sure[0] <= 120.0, sure[:3]
        assert motion is not None and motion.p_moving >= 0.9
        truth = walk.at(np.array([motion.stamp]))[0]
        d = motion.mean - truth
        assert d @ np.linalg.solve(motion.cov, d) < 13.8  # inside its 99.9 % ellipse
        v = (walk.at(np.array([motion.stamp + 0.5]))[0] - walk.at(np.array([motion.stamp - 0.5]))[0])
        dv = motion.velocity - v
        assert dv @ np.linalg.solve(motion.velocity_cov, dv) < 13.8 and np.trace(motion.velocity_cov) < 10.0


def test_a_mixture_of_two_places_by_hand():
    mean, cov = mixture(0.5, np.zeros(2), np.eye(2), np.array([2.0, 0.0]), np.eye(2))
    assert np.allclose(mean, [1.0, 0.0]) and np.allclose(cov, [[2.0, 0.0], [0.0, 1.0]])
    mean, cov = mixture(0.0, np.zeros(2), np.eye(2), np.array([9.0, 9.0]), 4.0 * np.eye(2))
    assert np.allclose(mean, 0.0) and np.allclose(cov, np.eye(2))


def test_the_switch_and_the_weighing_by_hand():
    # standing switchers 0.3 of the mass, movers 0.1, never-movers 0.6; over one mean stay 1 - 1/e of each side goes
    q = 1.0 - math.exp(-1.0)
    prior, came = switched(0.1, 0.6, SWITCH_S)
    assert prior == pytest.approx(0.1 * (1 - q) + 0.3 * q) and came == pytest.approx(0.3 * q / prior)
    assert switched(0.1, 0.6, 0.0) == pytest.approx((0.1, 0.0))
    # evidence 3:1 for the standing model: odds of motion 1:9 become 1:27; the never-movers take their share
    moving, never = weighed(0.1, 0.6, 3.0, 1.0)
    assert moving == pytest.approx(0.1 / (0.9 * 3.0 + 0.1)) and never == pytest.approx(0.6 * 3.0 / 2.8)
    assert weighed(0.1, 0.6, math.nan, 1.0) == (0.1, 0.6)


def test_a_transmitter_that_stands_long_is_trusted_to_stand_and_one_seen_moving_may_move_again():
    """Evidence of one nat for standing at every 10 s point: the two-kind switch's probability of motion sinks
    below what one kind alone holds it at (its inflow), and after a move the never-moving kind is gone."""
    def run(p_never, evidence):
        p = PRIOR_MOVING
        for e in evidence:
            prior, _ = switched(p, p_never, 10.0)
            p, p_never = weighed(prior, p_never, e, 1.0)
        return p, p_never
    alone, _ = run(0.0, [math.e] * 360)
    both, _ = run(NEVER_MOVES * (1.0 - PRIOR_MOVING), [math.e] * 360)
    inflow = -math.expm1(-10.0 / SWITCH_S)
    floor = inflow / (math.e - 1.0)  # one kind: p = (p + inflow) / e, for small p
    assert alone == pytest.approx(floor, rel=0.05) and both < 0.1 * floor
    _, never = run(NEVER_MOVES * (1.0 - PRIOR_MOVING), [math.e] * 100 + [1.0 / 50.0] * 10)
    assert never < 1e-6  # it moved: what is left is the kind that stands and moves in turn


def test_a_needle_along_the_line_of_sight_is_a_range_not_observed():
    first = ObservationPoint(0.0, 0.0, 0.0, 0.0, SIGMA, 1)
    watch = MotionWatch(first, 30.0, np.random.default_rng(1))
    rng = np.random.default_rng(2)
    along = np.column_stack([1000.0 + 300.0 * rng.standard_normal(1000), 10.0 * rng.standard_normal(1000)])
    watch.place, watch.weights = along, np.full(1000, 1e-3)
    assert not watch.motion().range_observed  # long along the sight line from (0, 0)
    watch.place = np.column_stack([1000.0 + 30.0 * rng.standard_normal(1000), 30.0 * rng.standard_normal(1000)])
    assert watch.motion().range_observed


def test_the_ou_step_keeps_the_speed_scale_and_a_standing_limit_is_the_static_bound():
    f, q = ou_transition(1e-9, 2.0, 60.0)
    assert np.allclose(f, np.eye(4)) and np.allclose(q, 0.0, atol=1e-9)
    f, q = ou_transition(5.0, 2.0, 60.0)
    a = math.exp(-5.0 / 60.0)
    assert q[2, 2] + a * a * 4.0 == pytest.approx(4.0)  # the velocity's variance stays the speed scale squared
    # a transmitter that cannot move: the posterior bound after every reading is the static CRLB of them all
    rng = np.random.default_rng(3)
    sensors = rng.uniform(0.0, 2000.0, (40, 2))
    truth = np.tile([800.0, 1200.0], (40, 1))
    sigmas = np.full(40, SIGMA)
    bound = pcrb_moving(truth, sensors, sigmas, np.arange(40.0), 1e-6, 60.0, prior_sd_m=1e5)
    assert bound[-1] == pytest.approx(crlb_rmse(truth[0], sensors, sigmas), rel=1e-3)
    assert np.all(np.diff(bound[5:]) <= 1e-9)  # more readings never loosen it


@pytest.mark.parametrize("value", [0.0, -5.0, math.nan, "fast"])
def test_a_speed_scale_that_is_no_positive_number_is_refused_at_start(value):
    with pytest.raises(ConfigError, match="max_transmitter_speed_mps"):
        LocalizerConfig().with_changes(max_transmitter_speed_mps=value)
    with pytest.raises(ConfigError, match="motion_model"):
        LocalizerConfig().with_changes(motion_model="walking")


@pytest.mark.parametrize("change, words", [
    ({"emitter_path": ((math.nan, 0.0),), "emitter_speed": 1.0}, "not a finite number"),
    ({"emitter_path": ((1000.0, 1000.0),), "emitter_speed": 1.0}, "no length"),
    ({"emitter_path": ((1200.0, 1000.0),), "emitter_speed": 0.0}, "positive number of m/s"),
    ({"emitter_path": ((1200.0, 1000.0),), "emitter_speed": 1.0, "emitter_start_s": -1.0}, "time >= 0"),
])
def test_a_transmitter_path_that_cannot_be_driven_is_refused_with_the_reason(change, words):
    from dataclasses import replace

    with pytest.raises(ValueError, match=words):
        simulate(replace(moving_cells()["walker"], **change), 1)


def test_a_moving_cell_simulates_bearings_to_where_the_transmitter_is_at_each_reading():
    data = simulate(moving_cells()["stand_walk_stand"], 1)
    t = data.bearings[:, 0]
    place = data.emitter_at(t)
    assert np.allclose(place[t < 300.0], [1000.0, 1000.0]) and np.allclose(place[t > 600.0], [1300.0, 1000.0])
    inliers = ~data.wild
    az = np.radians(90.0 - data.bearings[inliers, 1])
    true = np.arctan2(place[inliers, 1] - data.sensor_enu[inliers, 1], place[inliers, 0] - data.sensor_enu[inliers, 0])
    residual = np.degrees((az - true + np.pi) % (2 * np.pi) - np.pi)
    assert abs(np.median(residual)) < 0.5 and np.std(residual) < 3.0  # 2 deg noise about the moving truth


def test_the_json_line_carries_the_motion():
    est = Estimate(0.0, 1.0, 2.0, 39.0, 117.0, np.eye(2), 10, 2, 100.0, "afsa", motion="moving",
                   motion_probability=0.97, velocity=np.array([1.5, -0.5]), velocity_cov=0.1 * np.eye(2))
    line = est.to_json_dict()
    assert line["motion"] == "moving" and line["motion_probability"] == 0.97
    assert line["velocity"] == [1.5, -0.5] and line["velocity_cov"] == [[0.1, 0.0], [0.0, 0.1]]
    assert "velocity" not in Estimate(0.0, 1.0, 2.0, 39.0, 117.0, np.eye(2), 10, 2, 100.0, "afsa").to_json_dict()


def test_a_moving_transmitters_path_is_drawn_on_the_map_with_its_ellipses_over_time():
    import matplotlib.pyplot as plt

    from aoa_localizer.reporting.plots import PATH_ELLIPSES, draw_paths

    def at(stamp, east, north, channel="default"):
        return Estimate(stamp, east, north, 0.0, 0.0, 4.0 * np.eye(2), 10, 2, 100.0, "afsa", motion="moving",
                        channel=channel)

    walk = [at(float(t), 10.0 * t, 2.0 * t) for t in range(20)][::-1]  # out of order: drawn in time order
    other = [at(1.0, -50.0, 0.0, "f1"), at(2.0, -60.0, 5.0, "f1")]
    fig, ax = plt.subplots()
    drawn = draw_paths(ax, walk + other)
    lines = ax.get_lines()
    assert len(drawn) == 2 and np.allclose(drawn[0], [[10.0 * t, 2.0 * t] for t in range(20)])
    assert np.allclose(lines[0].get_xydata(), drawn[0])  # the path, then its ellipses
    rings = lines[1:1 + PATH_ELLIPSES]
    centres = np.array([r.get_xydata().mean(axis=0) for r in rings])
    assert np.allclose(centres[0], [0.0, 0.0], atol=0.1) and np.allclose(centres[-1], [190.0, 38.0], atol=0.1)
    assert np.all(np.diff(centres[:, 0]) > 0)  # spread along the path
    radius = np.hypot(*(rings[0].get_xydata() - centres[0]).T)
    assert np.allclose(radius, 2.0 * math.sqrt(5.991), rtol=0.02)  # the 95 % ellipse of a 2 m sigma
    assert len(lines) == 1 + PATH_ELLIPSES + 1 + 2  # the other channel: its path and both ellipses
    assert draw_paths(ax, []) == []
    plt.close(fig)


@pytest.mark.slow
def test_the_localizer_follows_a_walker_and_leaves_a_standing_transmitter_as_it_was():
    """End to end with the defaults (Localizer.run): one lap of the ring around a walker ends sure of motion; where
    the estimate follows the walker (the watch sure for long enough and no bearing offset learned from its drift),
    the walker is inside its ellipse and its velocity inside the velocity's; the last estimate is `moving` or the
    filter's `static` place held by a gate (motion_said), never undecided.
    The seed scenario's transmitter stands: every estimate `static`, the last with a small probability of motion
    and its usual error."""
    from dataclasses import replace

    from aoa_localizer import Localizer
    from aoa_localizer.engine.geodesy import LocalFrame
    from aoa_localizer.simulation.evaluation import scenario_config
    walker = moving_cells()["walker"]
    followed = 0
    for seed in (2, 3):  # both followed for a while (2 for 167 estimates), and both end held at the filter's place
        data = simulate(replace(walker, track=walker.track[:31]), seed)
        ests = [e for e in Localizer(scenario_config(data, LocalizerConfig(seed=1))).run(data.inputs())
                if e is not None]
        assert ests[-1].motion_probability >= 0.9 and ests[-1].motion in ("moving", "static")
        moving = [e for e in ests if e.motion == "moving"]
        followed += bool(moving)
        for last in moving[-1:]:
            d = (np.array(LocalFrame(*walker.datum).to_enu(last.lat, last.lon))
                 - data.emitter_at(np.array([last.stamp]))[0])
            # after one lap the range along the line of sight is barely observed: honest, if not sharp
            assert d @ np.linalg.solve(last.cov, d) < 13.8 and np.hypot(*d) < 500.0
            ahead, behind = data.emitter_at(np.array([last.stamp + 1.0, last.stamp - 1.0]))
            truth_v = (ahead - behind) / 2.0
            dv = np.asarray(last.velocity) - truth_v  # the walker's 1.4 m/s inside the velocity's own ellipse
            assert dv @ np.linalg.solve(last.velocity_cov, dv) < 13.8
    assert followed >= 1
    data = simulate("seed", 1)
    ests = [e for e in Localizer(LocalizerConfig(seed=1)).run(data.inputs()) if e is not None]
    assert all(e.motion == "static" for e in ests) and ests[-1].motion_probability < 0.1
    east, north = LocalFrame(*data.scenario.datum).to_enu(ests[-1].lat, ests[-1].lon)
    assert math.hypot(east - 1200.0, north - 800.0) < 5.0


@pytest.mark.slow
def test_a_cars_drift_is_not_taken_for_bearings_that_turn_with_the_vehicle():
    """A car at 15 m/s round a block, heard from a DF vehicle on a ring (the vehicle turns all the time): a fit that
    turns the bearings by the vehicle's course follows part of the car's drift, and was learned (307 s into data
    seed 0), after which the watch was off and no estimate held the car. A path of places split by time explains the
    drift about as well (the course was still learned, at 322 s, until it was charged the reference's prior odds as
    against north: checks._moving_explains_more): no course is learned, and the held place's ellipse holds the
    car."""
    from aoa_localizer import Localizer
    from aoa_localizer.engine.geodesy import LocalFrame
    from aoa_localizer.simulation.evaluation import scenario_config

    car = moving_cells()["car"]
    data = simulate(car, 0)
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=1000)))
    inside = []
    for event in data.inputs():
        if event[1].stamp > 400.0:
            break
        est = loc.feed(event)
        if est is not None and est.stamp > 200.0:
            d = np.array(LocalFrame(*car.datum).to_enu(est.lat, est.lon)) - data.emitter_at(np.array([est.stamp]))[0]
            inside.append(d @ np.linalg.solve(est.cov, d) < 5.99)
    assert loc.view().events["course_learned"] == 0 and len(inside) > 100 and np.mean(inside) > 0.7


def test_simulate_refuses_a_moving_run_mixed_with_another_scenario_and_a_bad_speed(cli):
    from aoa_localizer.tools.simulate import main

    res = cli(main, "--moving", "walker", "--co-channel", "600,1300")
    assert res.returncode == 2 and "--moving is a scenario of its own" in res.stderr
    res = cli(main, "--moving", "walker", "-p", "max_transmitter_speed_mps=-3")
    assert res.returncode == 2 and "max_transmitter_speed_mps" in res.stderr
    res = cli(main, "--moving", "skater")
    assert res.returncode == 2 and "invalid choice" in res.stderr


def test_a_moving_transmitters_path_is_a_line_in_the_kml_and_geojson():
    from aoa_localizer.engine.geodesy import LocalFrame
    from aoa_localizer.reporting import export
    from aoa_localizer.simulation.scenarios import DATUM

    frame = LocalFrame(*DATUM)

    def at(stamp, east, north, motion):
        lat, lon, _ = frame.to_geodetic(east, north)
        return Estimate(stamp, east, north, float(lat), float(lon), np.eye(2), 10, 2, 100.0, "afsa", motion=motion)

    ests = [at(1.0, 0.0, 0.0, "static"), at(2.0, 10.0, 0.0, "moving"), at(3.0, 20.0, 5.0, "moving"),
            at(4.0, 30.0, 9.0, "moving")]
    paths = export.moving_paths(ests)
    assert list(paths) == ["default"] and np.allclose(paths["default"], [[10, 0], [20, 5], [30, 9]])
    lines = [f for f in export.geojson(frame, ests[-1:], {}, paths)["features"] if f["properties"]["name"] ==
             "transmitter path"]
    assert len(lines) == 1 and len(lines[0]["geometry"]["coordinates"]) == 3
    assert "<name>transmitter path</name>" in export.kml(frame, ests[-1:], {}, paths)
    assert export.moving_paths(ests[:2]) == {}  # one moving estimate is no path


@pytest.mark.slow
def test_a_watch_that_fails_costs_the_motion_not_the_point(monkeypatch, caplog):
    """A failing watch (here: every step raises) is counted `internal_error` and logged; the filter's estimate goes
    on as without the watch."""
    from aoa_localizer import Localizer
    from aoa_localizer.engine.inference import motion

    def failing(self, readings, static):
        raise np.linalg.LinAlgError("Matrix is not positive definite")

    monkeypatch.setattr(motion.MotionWatch, "step", failing)
    data = simulate("seed", 1)
    loc = Localizer(LocalizerConfig(seed=1))
    ests = [e for e in loc.run(data.inputs()) if e is not None]
    loc_free = [e for e in Localizer(LocalizerConfig(seed=1, motion_model="static")).run(data.inputs()) if e]
    assert ests and math.isnan(ests[-1].motion_probability) and ests[-1].motion == "static"
    # the watch begins on one point and fails on the next, again and again: one failure every other point
    assert loc.view().rejected["internal_error"] == loc._channels.default.track.points_seen // 2
    assert (ests[-1].east, ests[-1].north) == (loc_free[-1].east, loc_free[-1].north)
    assert any("motion watch failed" in r.getMessage() for r in caplog.records)


def test_a_sure_watch_the_estimate_does_not_follow_is_said_and_the_estimate_is_not_tracking():
    """Where the channel learned a bearing offset the estimate keeps the filter's place (Held.motion_said); a watch
    sure of motion is then said in a warning and the estimate is never `tracking`; so is a probable motion the
    estimate does not follow yet; both keep the place, and their ellipse holds where the mover would be; what the
    count explains, or an improbable motion, leaves it as it was."""
    from aoa_localizer.engine.inference.motion import Motion
    from aoa_localizer.engine.outputs.estimates import with_motion
    from aoa_localizer.engine.types import EstimateState

    sure = Motion(10.0, 0.999, np.array([5.0, 5.0]), np.eye(2), np.array([1.0, 0.0]), np.eye(2), True)
    mean, cov = np.array([1.0, 2.0]), 4.0 * np.eye(2)
    out = with_motion(sure, None, mean, cov, EstimateState.TRACKING, [], unheeded=True)
    assert out[2] == EstimateState.POORLY_DETERMINED and out[0] is mean
    # by hand: the place stands; its covariance is 0.001 x 4 I + 0.999 x (I + [4, 3][4, 3]^T), the mover 5 m off
    held = 0.001 * 4.0 * np.eye(2) + 0.999 * (np.eye(2) + np.array([[16.0, 12.0], [12.0, 9.0]]))
    np.testing.assert_allclose(out[1], held)
    assert len(out[3]) == 1 and "look like a moving transmitter's (p = 1.00)" in out[3][0]
    assert out[4]["motion_probability"] == 0.999 and np.array_equal(out[4]["velocity"], [0.0, 0.0])
    # the place stands; the velocity's spread is the watch's second moment about zero, times p
    np.testing.assert_allclose(out[4]["velocity_cov"], 0.999 * (np.eye(2) + np.outer([1.0, 0.0], [1.0, 0.0])))
    # not yet followed (the watch not sure for long enough): the place stands, and it is not `tracking` either
    probable = with_motion(sure, None, mean, cov, EstimateState.TRACKING, [])
    assert probable[2] == EstimateState.POORLY_DETERMINED and probable[0] is mean
    np.testing.assert_allclose(probable[1], held)
    assert len(probable[3]) == 1 and "may be moving (p = 1.00)" in probable[3][0]
    # the count explains it (transmitters taking turns), or motion is improbable: as it was
    explained = with_motion(sure, None, mean, cov, EstimateState.TRACKING, [], explained=True)
    assert explained[2] == EstimateState.TRACKING and explained[3] == [] and explained[1] is cov
    unlikely = Motion(10.0, 0.2, np.array([5.0, 5.0]), np.eye(2), np.array([1.0, 0.0]), np.eye(2), True)
    quiet = with_motion(unlikely, None, mean, cov, EstimateState.TRACKING, [])
    assert quiet[2] == EstimateState.TRACKING and quiet[3] == [] and quiet[1] is cov


def test_a_refined_offset_keeps_the_watch_and_one_learned_or_taken_back_begins_it_again():
    """The moving cloud reads the bearings as given, so a refined bearing offset leaves it as it was (a drone whose
    drift the calibration kept refining as an offset, -54 to +27 deg, lost its track at each refinement: its ellipse
    held it 57-85 % of the time); learning an offset or taking one back changes the standing model its odds were
    weighed against, and the watch begins again on that point, unless it found motion probable (an offset learned
    from a mover's drift)."""
    from dataclasses import replace

    from aoa_localizer import Localizer
    from aoa_localizer.engine.inference.motion import UNSURE_P
    from aoa_localizer.engine.types import ObservationPoint

    track = Localizer(LocalizerConfig(seed=1))._channels.default.track
    point = [ObservationPoint(float(k), 10.0 * k, 0.0, math.radians(45.0), math.radians(1.0), 3) for k in range(5)]
    track._watch_motion(point[0])  # the first point begins the watch
    begun = track.watch
    assert begun is not None
    track.calibration.offset = math.radians(5.0)  # learned
    track._watch_motion(point[1])
    learned = track.watch
    assert learned is not begun and track.watched_offset == math.radians(5.0)
    track.calibration.offset = math.radians(-20.0)  # refined
    track._watch_motion(point[2])
    assert track.watch is learned and track.watch.stamp == 2.0 and track.watched_offset == math.radians(-20.0)
    track.calibration.offset = 0.0  # taken back
    track._watch_motion(point[3])
    assert track.watch is not learned and track.watch.stamp == 3.0 and track.watched_offset == 0.0
    track.motion = replace(track.motion or track.watch.motion(), p_moving=UNSURE_P)  # motion probable
    kept = track.watch
    track.calibration.offset = math.radians(5.0)  # learned from what may be a mover's drift
    track._watch_motion(point[4])
    assert track.watch is kept and track.watch.stamp == 4.0 and track.watched_offset == math.radians(5.0)
