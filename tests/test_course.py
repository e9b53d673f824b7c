"""Bearings from the vehicle's forward axis read as azimuths (engine/points/course.py): turned by the course over
ground, learned at a check when they explain the drive, and not taken for an emitter that moved."""
import math
import re
from dataclasses import replace

import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.engine.inference.point_batch import PointBatch
from aoa_localizer.engine.points.course import courses, turned
from aoa_localizer.engine.points.preprocess import Group, make_point
from aoa_localizer.engine.types import EstimateState, Reading
from aoa_localizer.simulation.evaluation import run
from aoa_localizer.simulation.scenarios import SCENARIOS, mounted, receiver_settings, robustness_cells, simulate


def reading(stamp: float, theta: float, v_east: float, v_north: float) -> Reading:
    return Reading(stamp, theta, 80.0, 0.02, 10.0 * stamp, 0.0, 0.0, v_east, v_north)


def test_a_slow_reading_holds_the_course_before_it_and_the_first_ones_take_the_first_moving_course():
    v_east = np.array([0.0, 0.0, 3.0, 0.5, 0.0, -2.0])
    v_north = np.array([0.0, 0.2, 3.0, 0.0, 4.0, 0.0])
    want = [math.pi / 4, math.pi / 4, math.pi / 4, math.pi / 4, math.pi / 2, math.pi]
    assert np.allclose(courses(v_east, v_north), want)
    assert np.allclose(courses(v_east[:2], v_north[:2], held=1.0), [1.0, 1.0])  # the course held from before
    assert np.allclose(courses(v_east[:2], v_north[:2]), [0.0, 0.0])  # never moved: nothing to turn by


def test_the_batch_turns_each_point_by_its_course_as_a_point_made_from_turned_readings():
    groups = [Group([reading(0.0, 0.1, 5.0, 0.0), reading(1.0, 0.12, 5.0, 0.0)]),
              Group([reading(2.0, -0.5, 0.0, 0.0)]),  # stopped: holds east
              Group([reading(3.0, 2.0, 0.0, -5.0), reading(4.0, 2.02, 0.0, -5.0), reading(5.0, 1.98, 0.0, -5.0)])]
    cfg = LocalizerConfig()
    pts = PointBatch(groups, cfg, course=True).points(None)
    assert np.allclose(pts.theta, [0.11, -0.5, 2.0 - math.pi / 2], atol=1e-9)
    held = math.nan
    for k, g in enumerate(groups):  # the track's way, a point at a time with the course held between them
        group, held = turned(g, held)
        assert math.isclose(make_point(group, cfg)[0].theta, pts.theta[k], abs_tol=1e-12)
    assert math.isclose(held, -math.pi / 2)


@pytest.mark.slow
@pytest.mark.parametrize("mount", [30.0, -45.0])
def test_vehicle_relative_bearings_configured_as_true_north_are_learned_and_the_emitter_found(mount):
    sc = mounted(SCENARIOS["seed"], mount)  # the array on the vehicle, the config left at true north
    for seed in (3, 4):
        res = run(simulate(sc, seed), LocalizerConfig(seed=seed))
        est = res.estimates[-1]
        assert res.scores["error"] < 10.0 and res.scores["inside95"]
        course = [w for w in est.warnings if "turn with the vehicle" in w]
        assert est.state is EstimateState.SUSPECT and len(course) == 1
        learned = re.search(r"mount_offset_deg to (-?[0-9.]+)\?", course[0])
        assert learned is not None and abs(float(learned.group(1)) - mount) < 3.0


@pytest.mark.slow
def test_right_settings_and_an_emitter_that_moved_are_not_read_as_turning_with_the_vehicle():
    cells = robustness_cells()
    moved = replace(cells["wild0"], points=80, moved_to=(300.0, 1500.0), moved_at_s=500.0)
    for sc, settings in ((moved, {}), (cells["wild20"], {}), (mounted(SCENARIOS["seed"], 30.0),
                                                              receiver_settings(30.0))):
        for seed in (0, 2):
            res = run(simulate(sc, seed), LocalizerConfig(seed=seed).with_changes(**settings))
            assert not any("turn with the vehicle" in w for e in res.estimates for w in e.warnings)
