"""Every point of a check remade at once (engine/inference/point_batch.py) agrees with make_point, point by point."""
import math

import numpy as np
import pytest
from conftest import track_of

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.inference.noise import NoiseModel
from aoa_localizer.engine.inference.point_batch import PointBatch, offset_point, sigmas
from aoa_localizer.engine.points.preprocess import Group, columns, make_point
from aoa_localizer.engine.types import Reading
from aoa_localizer.simulation.evaluation import scenario_config
from aoa_localizer.simulation.scenarios import simulate

FIELDS = ("stamp", "east", "north", "theta", "sigma", "n_readings", "gps_sigma")


def groups(rng: np.random.Generator) -> list[Group]:
    """Points of 1 to 40 readings (the plain-float and the numpy reference paths), some of each size, with wild
    readings to gate, unknown qualities, headings' sigmas and bearings either side of +-pi."""
    out = []
    for size in [1, 2, 3, 3, 3, 4, 5, 5, 8, 12, 33, 40, 1, 2]:
        centre = rng.uniform(-math.pi, math.pi)
        theta = centre + rng.normal(0, 0.02, size)
        theta[rng.random(size) < 0.2] += rng.uniform(0.5, 2.5)  # wild
        quality = rng.uniform(40, 100, size)
        quality[rng.random(size) < 0.2] = np.nan
        out.append(Group(Reading(float(100 + i), float((t + math.pi) % (2 * math.pi) - math.pi), float(q),
                                 float(rng.uniform(0.005, 0.05)), float(rng.uniform(-1e3, 1e3)),
                                 float(rng.uniform(-1e3, 1e3)), float(rng.uniform(0, 5)), float(rng.normal(0, 10)),
                                 float(rng.normal(0, 10)),
                                 float(rng.uniform(0, 0.01)))
                         for i, (t, q) in enumerate(zip(theta, quality, strict=True))))
    return out


def fitted() -> NoiseModel:
    model = NoiseModel(0.05)
    model.k = np.linspace(0.7, 3.1, model.k.size)[::-1].copy()  # a scale per quality band and for unknown quality
    return model


@pytest.mark.parametrize("weighting", ["inverse_variance", "equal", "paper"])
@pytest.mark.parametrize("noise", [None, "fitted"])
@pytest.mark.parametrize("offset", [0.0, 0.3, -3.0])
def test_the_batch_remakes_each_point_as_make_point_does(weighting, noise, offset):
    cfg = LocalizerConfig(point_weighting=weighting, df_correlation=0.3)
    model = fitted() if noise else None
    gs = groups(np.random.default_rng(7))
    batch = PointBatch(gs, cfg)
    built = batch.built(model, offset)
    pts = batch.points(model, offset)
    assert len(built) == len(gs) == len(pts)
    gated = 0
    for k, g in enumerate(gs):
        ref, ref_kept = offset_point(make_point(g, cfg, sigmas(g, model) if model else None), offset)
        point, kept = built[k]
        assert np.array_equal(kept, ref_kept)
        gated += int((~kept).sum())
        for name in FIELDS:
            a, b = getattr(point, name), getattr(ref, name)
            if name == "theta":
                a, b = math.remainder(a - b, 2 * math.pi), 0.0
            assert a == pytest.approx(b, rel=1e-12, abs=1e-12), (k, name)
        assert (pts.east[k], pts.north[k], pts.theta[k], pts.sigma[k], pts.gps[k]) == (
            point.east, point.north, point.theta, point.sigma, point.gps_sigma)
    assert gated > 0  # the gate was exercised
    velocity = [[columns(g).v_east.mean(), columns(g).v_north.mean()] for g in gs]
    assert batch.velocity() == pytest.approx(np.array(velocity), rel=1e-12, abs=1e-12)


def test_an_empty_batch_has_no_points():
    batch = PointBatch([], LocalizerConfig())
    assert batch.built(None) == [] and len(batch.points(fitted(), 0.2)) == 0


def test_a_calibration_remakes_the_points_after_its_snapshot_as_make_does():
    """A check's result rebuilds the track's points: those it did not make (they came after its snapshot) are made
    together as a batch, and each is the point the calibrator's make() gives under the new noise and offset."""
    data = simulate("seed", 1)
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=1)))
    for event in list(data.inputs())[:200]:
        loc.feed(event)
    track = track_of(loc)
    cal = track.calibration
    # none made by a check: all as a batch
    rebuilt = cal.apply(fitted(), np.array([100.0, 200.0]), {}, 0.05, False, track.window).window
    assert len(rebuilt) == len(track.window) > 10
    for entry in rebuilt:
        ref, ref_kept = cal.make(entry.readings)
        for name in FIELDS:
            assert getattr(entry.point, name) == pytest.approx(getattr(ref, name), rel=1e-12, abs=1e-12), name
        assert entry.gated == int((~ref_kept).sum())
