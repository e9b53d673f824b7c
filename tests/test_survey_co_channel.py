"""Counting an id's transmitters in the survey model (pooled/transmitters.py; issue 54, "every way in"): fixed
stations hearing two transmitters that take turns give both, through `locate_pooled`, `locate` and a Localizer
alike; one transmitter heard by biased stations stays one, whether the stations read together or one after another
(a surveyor's stops), since a biased station is one site, not a second place."""
import json
import math

import numpy as np
import pytest

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.pooled.solver import locate_pooled
from aoa_localizer.simulation.surveys import DATUM, shared_frequency
from aoa_localizer.tools import locate

FRAME = LocalFrame(*DATUM)


def truth_inside(t, truths: np.ndarray) -> int:
    """Which of `truths` the transmitter `t` is nearest, asserting that one is inside its 95 % ellipse."""
    east, north = FRAME.to_enu(t.lat, t.lon)
    miss = truths - [east, north]
    k = int(np.argmin(np.hypot(*miss.T)))
    assert float(miss[k] @ np.linalg.solve(t.cov, miss[k])) < -2.0 * math.log(0.05)
    return k


@pytest.mark.slow
@pytest.mark.parametrize("together", [True, False])
def test_stations_hearing_two_transmitters_in_turns_give_both(together):
    heard = shared_frequency(np.random.default_rng(1), 2, together)
    fix = locate_pooled(heard.readings(), max_k=3).fixes["x"]
    assert fix.count.count == 2 and fix.count.probability > 0.95
    first, second = fix.count.transmitters
    assert sorted(truth_inside(t, heard.transmitters) for t in (first, second)) == [0, 1]
    truth = sorted(np.bincount(heard.source) / len(heard.source))  # the air time each had (0.32 and 0.28 here)
    assert [second.share, first.share] == pytest.approx(truth, abs=0.05)
    assert str(fix.state) == "poorly_determined" and any("2 transmitters" in w for w in fix.warnings)


@pytest.mark.slow
@pytest.mark.parametrize("together", [True, False])
def test_one_transmitter_heard_by_biased_stations_stays_one(together):
    for seed in range(3):
        fix = locate_pooled(shared_frequency(np.random.default_rng(seed), 1, together).readings(), max_k=3).fixes["x"]
        assert fix.count.count == 1 and not fix.count.transmitters


@pytest.mark.slow
def test_an_id_is_not_counted_with_max_k_1_few_readings_or_no_stamps():
    readings = shared_frequency(np.random.default_rng(1), 2).readings()
    assert locate_pooled(readings, max_k=1).fixes["x"].count is None
    assert locate_pooled(readings[:24], max_k=3).fixes["x"].count is None
    readings[5] = readings[5].__class__(**{**readings[5].__dict__, "stamp": math.nan})
    assert locate_pooled(readings, max_k=3).fixes["x"].count is None  # turns need every reading's time


@pytest.mark.slow
def test_locate_and_a_localizer_give_the_same_transmitters(tmp_path, cli):
    readings = shared_frequency(np.random.default_rng(2), 2, seconds=240.0).readings()
    path = tmp_path / "two.csv"
    path.write_text("time,lat,lon,azimuth_deg,station,id\n" + "".join(
        f"{1.7e9 + r.stamp:.1f},{r.lat:.8f},{r.lon:.8f},{r.azimuth_deg:.3f},{r.station},x\n" for r in readings))
    res = cli(locate.main, path, "--output", tmp_path / "out.jsonl", "--report", tmp_path / "report")
    assert res.returncode == 0, res.stderr
    line = json.loads((tmp_path / "out.jsonl").read_text())
    assert line["transmitter_count"] == 2 and len(line["transmitters"]) == 2
    assert "transmitter 2 of 2" in (tmp_path / "report" / "emitter.kml").read_text()

    loc = Localizer(LocalizerConfig(seed=1))
    for r in readings:
        loc.add_station(r.station, fixed=True, position=(r.lat, r.lon))
    for r in readings:
        loc.add_bearing(1.7e9 + r.stamp, r.azimuth_deg, math.nan, station=r.station)
    loc.flush()
    final = loc.finish()
    assert final.algorithm == "survey" and final.transmitter_count == 2
    for mine, theirs in zip(final.transmitters, line["transmitters"], strict=True):
        assert mine.lat == pytest.approx(theirs["lat"], abs=2e-4) and mine.lon == pytest.approx(theirs["lon"], abs=3e-4)
