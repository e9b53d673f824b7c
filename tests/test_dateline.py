"""Places near the antimeridian and the poles, by every path (issue 64, item 3): the survey model, `locate`'s
filter and the engine driving. The survey model once put its frame at the plain mean of the stations' longitudes:
four stations on both sides of 180 deg were fixed at (-60.9, 25.5), 27,000 km away."""
import json
import math

import numpy as np
import pymap3d
import pytest
from pymap3d.vincenty import vdist

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.geodesy import centroid
from aoa_localizer.pooled import SurveyReading, locate_pooled
from aoa_localizer.tools.locate import main as locate_main

# (lat, lon) of a transmitter: on the antimeridian, either side of it, and near each pole across it
PLACES = [(10.0, 180.0), (10.0, -179.999), (-40.0, 179.9995), (89.5, 30.0), (-89.5, 179.99), (89.95, -179.999)]


def azimuth(lat, lon, target):
    return float(pymap3d.geodetic2aer(target[0], target[1], 0.0, lat, lon, 0.0)[0])


def stations(target, spread_m=1000.0):
    """Five stations about `spread_m` from the target, on the far side of the antimeridian where it is near."""
    out = []
    for k, heading in enumerate((45.0, 135.0, 225.0, 315.0, 90.0)):
        lat, lon = pymap3d.vincenty.vreckon(target[0], target[1], spread_m * (1 + 0.2 * k), heading)
        out.append((float(lat), (float(lon) + 180.0) % 360.0 - 180.0))
    return out


def metres(lat, lon, target) -> float:
    return float(vdist(lat, lon, target[0], target[1])[0])


@pytest.mark.parametrize("target", PLACES)
def test_the_centroid_lies_among_the_points(target):
    lat, lon = centroid(*zip(*stations(target), strict=True))
    assert metres(lat, lon, target) < 1000.0


@pytest.mark.parametrize("target", PLACES)
def test_the_survey_model_fixes_a_transmitter_across_the_antimeridian_and_near_a_pole(target):
    """Exact bearings of three readings a station: the fix at the target, tracking, no station named as far off.
    Near a pole the stations' norths differ by tens of degrees, which the frame must turn away."""
    readings = [SurveyReading("tx", lat, lon, azimuth(lat, lon, target), f"s{k}", "r", 0.2)
                for k, (lat, lon) in enumerate(stations(target)) for _ in range(3)]
    fix = locate_pooled(readings).fixes["tx"]
    assert metres(fix.lat, fix.lon, target) < 2.0
    assert -180.0 <= fix.lon <= 180.0 and fix.state.value == "tracking"


@pytest.mark.parametrize("target", [PLACES[0], PLACES[4]])
@pytest.mark.parametrize("model", ["pooled", "filter"])
def test_locate_across_the_antimeridian_by_either_model(tmp_path, target, model):
    rows = ["time,lat,lon,azimuth_deg,station,id"]
    for k, (lat, lon) in enumerate(stations(target)):
        rows += [f"{1700000000 + 30 * k + j},{lat:.8f},{lon:.8f},{azimuth(lat, lon, target):.4f},s{k},tx"
                 for j in range(3)]
    (tmp_path / "s.csv").write_text("\n".join(rows) + "\n")
    assert locate_main([str(tmp_path / "s.csv"), "--model", model, "--output", str(tmp_path / "o.jsonl")]) == 0
    fix = json.loads((tmp_path / "o.jsonl").read_text().splitlines()[0])
    assert metres(fix["lat"], fix["lon"], target) < 5.0 and fix["state"] == "tracking"


@pytest.mark.slow
@pytest.mark.parametrize("target", [PLACES[0], (89.9, 180.0)])
def test_the_engine_driving_a_circle_across_the_antimeridian_or_round_a_pole(target):
    """A vehicle circling 500 m around the target, 1 deg bearings: its track crosses 180 deg (and, near the pole,
    the meridians turn under it); the estimate is at the target within its ellipse."""
    rng = np.random.default_rng(5)
    loc = Localizer(LocalizerConfig(seed=2))
    def at(t: float) -> tuple[float, float]:
        lat, lon = pymap3d.vincenty.vreckon(target[0], target[1], 500.0, 1.5 * t)
        return float(lat), (float(lon) + 180.0) % 360.0 - 180.0

    for t in range(240):
        loc.add_fix(float(t), *at(t))
        # the bearing from where the antenna is at its own stamp: taken from the fix's place half a second
        # earlier, it is 0.75 deg off on this circle, an error the engine rightly learns as an offset or motion
        loc.add_bearing(t + 0.5, (azimuth(*at(t + 0.5), target) + rng.normal(0.0, 1.0)) % 360.0, 80.0)
    loc.flush()
    est = loc.view().estimate
    loc.close()
    assert est is not None and est.state.value == "tracking"
    assert metres(est.lat, est.lon, target) < max(10.0, 3.0 * math.sqrt(np.trace(est.ground_cov)))
