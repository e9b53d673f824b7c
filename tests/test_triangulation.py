import math

import numpy as np
import pytest

from aoa_localizer.engine.inference.triangulation import (
    good_pairs,
    initial_particles,
    intersect_rays,
    sorted_pairs,
)
from aoa_localizer.engine.types import ObservationPoint


def test_rays_cross_where_hand_geometry_says():
    xy, s1, s2 = intersect_rays([0.0, 0.0], math.radians(45), [100.0, 0.0], math.radians(135))
    assert xy == pytest.approx([50.0, 50.0])
    assert s1 == pytest.approx(50 * math.sqrt(2)) and s2 == pytest.approx(50 * math.sqrt(2))


def test_eqs_22_23_as_printed_agree_with_the_ray_form():
    rng = np.random.default_rng(0)
    p1, p2 = rng.uniform(-500, 500, (2, 20, 2))
    t1, t2 = rng.uniform(-1.4, 1.4, (2, 20))
    xy, _, _ = intersect_rays(p1, t1, p2, t2)
    x, y = intersect_tan(p1[:, 0], p1[:, 1], t1, p2[:, 0], p2[:, 1], t2)
    assert np.allclose(xy[:, 0], x) and np.allclose(xy[:, 1], y)


def test_crossing_behind_an_antenna_has_negative_range_and_parallel_rays_none():
    _, s1, _ = intersect_rays([0.0, 0.0], math.radians(-135), [100.0, 0.0], math.radians(135))
    assert s1 < 0
    xy, s1, s2 = intersect_rays([0.0, 0.0], 0.3, [0.0, 10.0], 0.3)
    assert np.isnan(s1) and np.isnan(s2)


def _points(emitter, positions, sigma_deg=1.0, noise=None):
    pts = []
    for k, (e, n) in enumerate(positions):
        theta = math.atan2(emitter[1] - n, emitter[0] - e) + (0.0 if noise is None else noise[k])
        pts.append(ObservationPoint(float(k), e, n, theta, math.radians(sigma_deg), 1))
    return pts


def test_sorted_pairs_are_half_the_count_apart_in_bearing_order():
    pts = _points((1000, 1000), [(x, 0.0) for x in (0, 300, 100, 200)])
    i, j = sorted_pairs(pts)
    theta = np.array([p.theta for p in pts])
    assert len(i) == 2 and np.all(theta[j] > theta[i])  # bearings to the emitter shrink... sorted by angle
    assert np.all(np.abs(np.argsort(np.argsort(theta))[j] - np.argsort(np.argsort(theta))[i]) == 2)


def test_initial_particles_gather_around_the_emitter():
    pts = _points((1200, 800), [(x, 0.2 * x) for x in np.linspace(0, 1000, 10)])
    x, why = initial_particles(pts, 100, 10.0, 0.6, np.random.default_rng(1))
    assert why == "" and x.shape == (100, 2)
    assert np.linalg.norm(np.median(x, axis=0) - [1200, 800]) < 60


def test_nearly_collinear_bearings_wait_and_say_why():
    pts = _points((1500, 1500), [(t, t) for t in np.linspace(0, 1000, 12)])  # driving straight at the emitter
    x, why = initial_particles(pts, 100, 10.0, 0.6, np.random.default_rng(1))
    assert x is None and "nearly parallel" in why


def test_one_wild_bearing_does_not_seed_the_cloud():
    positions = [(x, 0.4 * x) for x in np.linspace(0, 330, 12)]  # bearings span only ~4 degrees
    noise = np.zeros(12)
    noise[11] = math.radians(40)  # the newest bearing is multipath: it crosses the others steeply
    pts = _points((1200, 800), positions, noise=noise)
    assert good_pairs(pts, 10.0, 0.0)[0].size == 1  # without the support check it would seed the cloud
    i, j, why = good_pairs(pts, 10.0, 0.6)
    assert i.size == 0 and "supported" in why


def intersect_tan(x1, y1, t1, x2, y2, t2):
    """Eqs. 22-23 as printed: the crossing of two bearing lines (ENU angles), with tangents."""
    a, b = np.tan(t1), np.tan(t2)
    x = (y2 - y1 + x1 * a - x2 * b) / (a - b)
    y = (a * b * (x1 - x2) + y2 * a - y1 * b) / (a - b)
    return x, y
