import math

import numpy as np
import pytest

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.points.preprocess import (
    SMALL_POINT,
    Group,
    PointBuilder,
    columns,
    corrected_mean_coefficients,
    make_point,
    make_point_arrays,
    point_coefficients,
    quality_weight,
    reading_sigma,
)
from aoa_localizer.engine.types import Estimate, Reading


def test_quality_weight_eq20_by_hand():
    # Q >= 85: (Q-85)/150; 70..85: (Q-70)/375 + 1/8; 55..70: (Q-55)/600 + 1/4.
    assert quality_weight(100) == pytest.approx(0.1)
    assert quality_weight(85) == pytest.approx(0.0)
    assert quality_weight(84) == pytest.approx(14 / 375 + 0.125)
    assert quality_weight(70) == pytest.approx(0.125)
    assert quality_weight(55) == pytest.approx(0.25)
    assert quality_weight(60) == pytest.approx(5 / 600 + 0.25)


def test_quality_weight_rule_below_55_continues_the_papers_pattern():
    assert quality_weight(40) == pytest.approx(3 / 8)
    assert quality_weight(47.5) == pytest.approx(7.5 / 825 + 3 / 8)
    assert quality_weight(54.999) == pytest.approx(14.999 / 825 + 3 / 8)
    assert quality_weight(float("nan")) == 0.0


def test_corrected_mean_coefficients_match_the_papers_recursion():
    gammas = np.array([10.0, 12.0, 9.0, 11.5])
    w = quality_weight(np.array([90.0, 60.0, 75.0, 100.0]))
    a = corrected_mean_coefficients(w)
    assert a.sum() == pytest.approx(1.0)
    assert a @ gammas == pytest.approx(recursive_corrected_mean(gammas, w))


def test_recursive_corrected_mean_by_hand():
    # n=1: mean 10, corrected 10; n=2 (W=0.5): mean 11, corrected 12 - 1*0.5 = 11.5; mean of (10, 11.5) = 10.75.
    assert recursive_corrected_mean([10.0, 12.0], [0.0, 0.5]) == pytest.approx(10.75)
    a = corrected_mean_coefficients([0.0, 0.5])
    assert a == pytest.approx([0.5 * (1 + 0.5 / 2), 0.5 * (0.5 + 0.5 / 2)])


def _reading(theta_deg, q=90.0, sigma_deg=1.0, t=0.0, e=0.0, n=0.0):
    return Reading(t, math.radians(theta_deg), q, math.radians(sigma_deg), e, n)


def test_point_bearing_is_circular_across_the_wrap():
    cfg = LocalizerConfig(point_weighting="equal")
    p, kept = make_point([_reading(179.0), _reading(-179.0), _reading(179.5), _reading(-179.5)], cfg)
    assert kept.all()
    assert abs(abs(p.theta) - math.pi) < 1e-9  # 180 deg, not 0


def test_point_variance_counts_correlated_readings_honestly():
    readings = [_reading(10.0 + 0.01 * i, sigma_deg=2.0) for i in range(10)]
    independent, _ = make_point(readings, LocalizerConfig(point_weighting="equal", df_correlation=0.0))
    correlated, _ = make_point(readings, LocalizerConfig(point_weighting="equal", df_correlation=1.0))
    assert independent.sigma == pytest.approx(math.radians(2.0) / math.sqrt(10))
    assert correlated.sigma == pytest.approx(math.radians(2.0))  # fully correlated: one reading's worth


def test_inverse_variance_weights_and_position_follow_the_coefficients():
    a = point_coefficients(np.array([90.0, 90.0]), np.radians([1.0, 2.0]), "inverse_variance")
    assert a == pytest.approx([0.8, 0.2])
    p, _ = make_point([_reading(10.0, sigma_deg=1.0, e=0.0), _reading(20.0, sigma_deg=2.0, e=10.0)],
                      LocalizerConfig(point_weighting="inverse_variance"))
    assert math.degrees(p.theta) == pytest.approx(12.0)
    assert p.east == pytest.approx(2.0)
    assert p.sigma == pytest.approx(math.radians(math.sqrt(0.8**2 * 1 + 0.2**2 * 4)))


def test_wild_reading_inside_a_point_is_gated_and_counted():
    readings = [_reading(30.0), _reading(30.5), _reading(29.5), _reading(200.0), _reading(30.2)]
    p, kept = make_point(readings, LocalizerConfig())
    assert kept.tolist() == [True, True, True, False, True] and p.n_readings == 4
    assert math.degrees(p.theta) == pytest.approx(30.05, abs=0.3)


def test_reading_sigma_models():
    cfg = LocalizerConfig(sigma_model="quality", sigma_q100_deg=1.0, sigma_q40_deg=8.0)
    sigmas = [reading_sigma(q, cfg) for q in (100.0, 40.0, 70.0, float("nan"), 20.0)]
    assert np.degrees(sigmas) == pytest.approx([1, 8, 4.5, 8, 8])
    assert math.degrees(reading_sigma(50.0, LocalizerConfig(bearing_sigma_deg=2.5))) == pytest.approx(2.5)


def test_point_builder_closes_on_time_distance_and_count():
    cfg = LocalizerConfig(obs_max_duration_s=1.0, obs_max_distance_m=10.0, obs_max_readings=3)
    b = PointBuilder(cfg)
    assert b.add(_reading(1, t=0.0)) == [] and b.add(_reading(1, t=0.5)) == []
    closed = b.add(_reading(1, t=1.6))  # more than 1 s after the first: closes the first two
    assert [len(g) for g in closed] == [2]
    assert [len(g) for g in b.add(_reading(1, t=1.7, e=20.0))] == [1]  # 20 m away
    b.add(_reading(1, t=1.8, e=20.0))
    assert [len(g) for g in b.add(_reading(1, t=1.9, e=20.0))] == [3]  # full at 3 readings
    assert b.flush() is None


def test_a_point_spans_at_most_a_share_of_its_range_to_the_channels_estimate():
    """Readings 2 m apart: 10 m points far from the estimate (or without one), a reading a point within 40 m of it
    (5 % of 30 m is 1.5 m); `obs_max_range_share: 0` keeps 10 m points everywhere."""
    def sizes(cfg, emitter):
        b = PointBuilder(cfg)
        b.emitter = emitter
        closed = [len(g) for i in range(12) for g in b.add(_reading(1, t=0.1 * i, e=2.0 * i))]
        return closed + [len(b.flush() or [])]

    cfg = LocalizerConfig()
    assert sizes(cfg, None) == [6, 6] == sizes(cfg, (5000.0, 0.0))  # 10 m: the 7th reading is 12 m from the 1st
    assert sizes(cfg, (10.0, 30.0)) == [1] * 12
    assert sizes(cfg.with_changes(obs_max_range_share=0.0), (10.0, 30.0)) == [6, 6]


def test_a_channels_builders_take_its_estimates_place():
    loc = Localizer(LocalizerConfig(seed=1))
    channel = loc._channels.default
    channel.builder("car")
    channel.published(Estimate(0.0, 120.0, -40.0, 39.0, 117.0, np.eye(2), 3, 3, 100.0, "afsa"))
    assert channel.builders["car"].emitter == (120.0, -40.0)
    assert channel.builder("mast").emitter == (120.0, -40.0)  # a station heard later starts with it too
    channel.published(Estimate(0.0, 5.0, 5.0, 39.0, 117.0, np.eye(2), 3, 3, 100.0, "afsa", state="poorly_determined"))
    assert channel.builders["car"].emitter is None  # a provisional or wide place: the configured span


def random_group(rng, n):
    """n readings round a random bearing, a fifth of them wild, with random sigmas, qualities and positions, and
    half the time a random heading sigma."""
    theta = rng.uniform(-math.pi, math.pi) + rng.normal(0.0, 0.05, n) + (rng.random(n) < 0.2) * rng.uniform(-3, 3, n)
    heading = rng.uniform(0.0, 0.1, n) * (rng.random() < 0.5)
    return [Reading(100.0 + 0.1 * i, float(theta[i]), float(rng.uniform(40, 100)), float(rng.uniform(0.01, 0.1)),
                    float(rng.normal(0, 100)), float(rng.normal(0, 100)), float(rng.uniform(0, 3)),
                    heading_sigma=float(heading[i])) for i in range(n)]


@pytest.mark.slow
def test_a_small_point_in_plain_floats_is_the_numpy_reference_to_rounding():
    """Up to SMALL_POINT readings a point is made in plain floats; the numpy code (any size) is the reference:
    the same mask and the same point to 1e-12, whatever the weighting, correlation, sigmas and wild readings. A
    fields-only group (as the worker gets it) gives exactly the point its readings give."""
    rng = np.random.default_rng(5)
    for trial in range(1500):
        n = int(rng.integers(1, SMALL_POINT + 1))
        cfg = LocalizerConfig(df_correlation=float(rng.uniform(0.0, 0.9)),
                              point_weighting=("inverse_variance", "equal")[trial % 2])
        readings = random_group(rng, n)
        sigma = None if trial % 3 == 0 else np.array([r.sigma for r in readings]) * rng.uniform(0.5, 2.0, n)
        point, kept = make_point(readings, cfg, sigma)
        ref, ref_kept = make_point_arrays(readings, cfg, sigma)
        assert np.array_equal(kept, ref_kept) and point.n_readings == ref.n_readings
        assert abs(math.remainder(point.theta - ref.theta, 2 * math.pi)) < 1e-12
        for f in ("stamp", "east", "north", "sigma", "gps_sigma"):
            assert getattr(point, f) == pytest.approx(getattr(ref, f), rel=1e-12, abs=1e-12), f
        fields_only = Group(cols=columns(readings))
        again, again_kept = make_point(fields_only, cfg, sigma)
        assert again == point and np.array_equal(again_kept, kept)


def test_a_point_adds_its_readings_heading_sigma_whole_on_both_paths():
    """Four readings of 0.02 rad turned by headings of sigma 0.03 rad: the receiver's errors average down to 0.01
    rad, the heading's error is one error for the point, so its sigma is sqrt(0.01^2 + 0.03^2)."""
    readings = [Reading(float(i), 0.1, 80.0, 0.02, 0.0, 0.0, heading_sigma=0.03) for i in range(4)]
    cfg = LocalizerConfig()
    expected = math.sqrt(0.01**2 + 0.03**2)
    assert make_point(readings, cfg)[0].sigma == pytest.approx(expected)
    assert make_point_arrays(readings, cfg)[0].sigma == pytest.approx(expected)


def test_an_even_count_has_two_central_readings_and_the_first_is_the_median_on_both_paths():
    """Readings at 0, 10, 20, 30 mrad: the 10 and 20 mrad ones are equally central (spreads 40 mrad); the first
    wins, so with a gate of 3 x 5 mrad the 30 mrad reading is the wild one (the 0 mrad one would be from 20)."""
    cfg = LocalizerConfig(point_gate_sigma=3.0)
    readings = [Reading(float(i), 0.01 * i, 80.0, 0.005, 0.0, 0.0) for i in range(4)]
    assert make_point(readings, cfg)[1].tolist() == [True, True, True, False]
    assert make_point_arrays(readings, cfg)[1].tolist() == [True, True, True, False]


def test_more_readings_than_a_small_point_are_made_by_the_numpy_code():
    readings = random_group(np.random.default_rng(1), SMALL_POINT + 5)
    cfg = LocalizerConfig()
    assert make_point(readings, cfg)[0] == make_point_arrays(readings, cfg)[0]


def recursive_corrected_mean(gammas, weights) -> float:
    """The paper's recursion (eqs. 19-21) literally, on unwrapped angles: the reference for tests."""
    mean = cmean = 0.0
    for n, (g, w) in enumerate(zip(gammas, weights, strict=False), start=1):
        mean = ((n - 1) * mean + g) / n
        corrected = g - (g - mean) * w
        cmean = ((n - 1) * cmean + corrected) / n
    return cmean


def test_a_group_gives_back_its_readings_and_costs_a_quarter_of_them():
    """A closed point's readings are kept as one array of their fields (a channel keeps thousands): indexing,
    slicing and iterating give the same readings again, stations included, and the group costs under a quarter of
    the Reading objects it replaces."""
    import tracemalloc

    rng = np.random.default_rng(4)
    readings = [Reading(*(float(v) for v in rng.random(10)), station="" if k % 3 else "mast")
                for k in range(40)]
    g = Group(readings)
    assert len(g) == 40 and list(g) == readings and g[-1] == readings[-1] and g[3:7] == readings[3:7]
    assert g[0].station == "mast" and g[1].station == ""
    with pytest.raises(IndexError):
        g[40]
    assert all(np.array_equal(a, b) for a, b in zip(columns(g), columns(readings), strict=True))
    one = Group(readings[1:3])
    assert one.stations == "" and [r.station for r in one] == ["", ""]
    assert not Group() and columns(Group(cols=columns(readings))).theta.tolist() == [r.theta for r in readings]

    rows = rng.random((2000, 10))
    Group([Reading(*map(float, row)) for row in rows])  # the tuples' free list filled: not the group's
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        as_objects = [Reading(*map(float, row)) for row in rows]
        objects = tracemalloc.get_traced_memory()[0] - base
        base = tracemalloc.get_traced_memory()[0]
        as_group = Group(as_objects)
        group = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    assert len(as_group) == 2000 and 0 < group < objects / 4, (group, objects)
