"""Jobs in pieces (slices.py): how many pieces a call makes, a piece's exception, a sliced check's result against the
whole one, and a reproducible run that no idle call and no clock can change."""
import logging

import numpy as np
import pytest
from conftest import track_of

from aoa_localizer.engine import checks, slices
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.evaluation import scenario_config
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.scenarios import simulate
from aoa_localizer.engine.slices import SlicedJob, run_whole


def counted(made: list[int], pieces: int, fail_at: int = -1) -> slices.Steps[str]:
    """`pieces` pieces, each noted in `made`; the one numbered `fail_at` raises."""
    for i in range(pieces):
        if i == fail_at:
            raise ValueError("piece failed")
        made.append(i)
        yield
    return "result"


@pytest.mark.parametrize(("points", "per_call"), [(0, 12), (20, 10), (100, 6), (236, 3), (1200, 1), (5000, 1)])
def test_a_job_makes_the_pieces_its_points_allow_per_call(points, per_call):
    """max(1, 12 // (1 + K / 100)) pieces per call, by hand: 12 / 1.2 = 10, 12 / 2 = 6, 12 / 3.36 = 3.57."""
    made: list[int] = []
    job = SlicedJob(counted(made, 25), points)
    assert job.pieces == per_call
    job.advance()
    assert len(made) == min(per_call, 25) and not job.done()
    job.advance()
    assert len(made) == min(2 * per_call, 25)
    assert job.result() == "result" and made == list(range(25)) and job.done()
    job.advance()  # nothing left to make
    assert made == list(range(25))


def test_a_piece_that_raises_ends_the_job_and_its_result_raises():
    made: list[int] = []
    job = SlicedJob(counted(made, 10, fail_at=3), 5000)
    for _ in range(3):
        job.advance()
    assert not job.done()
    job.advance()
    assert job.done() and made == [0, 1, 2]
    with pytest.raises(ValueError, match="piece failed"):
        job.result()
    assert run_whole(counted([], 4)) == "result"


@pytest.mark.slow
def test_a_check_made_a_piece_at_a_time_finds_what_the_whole_check_finds():
    """The same snapshot, checked whole and one piece per call: the same noise, modes and points to the last bit."""
    data = simulate("urban", 1)
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=2)))
    for event in list(data.inputs())[:1500]:
        loc.feed(event)
    snap = track_of(loc).snapshot()
    whole = checks.run_check(snap)
    job = SlicedJob(checks.check(snap), 10**6)
    calls = 0
    while not job.done():
        job.advance()
        calls += 1
    sliced = job.result()
    assert calls > 20  # many pieces, one per call
    assert [m.mean.tolist() for m in sliced.modes] == [m.mean.tolist() for m in whole.modes]
    assert sliced.noise is not None and whole.noise is not None
    assert sliced.noise.k.tolist() == whole.noise.k.tolist()
    assert sliced.noise.reading_outlier_prob == whole.noise.reading_outlier_prob
    assert [p for p, _ in sliced.built] == [p for p, _ in whole.built]
    loc.close()


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["urban", "homing"])
def test_a_reproducible_run_is_the_same_with_idle_calls_between_inputs(scenario):
    """Jobs advance with the points alone: idle() between every input changes nothing, and the run finds the
    emitter (a job that never finished used to leave the start to the end of data)."""
    logging.getLogger("aoa_localizer").setLevel(logging.ERROR)
    data = simulate(scenario, 3)
    ends = []
    for idle in (False, True):
        loc = Localizer(scenario_config(data, LocalizerConfig(seed=4)))
        started_at = None
        for i, event in enumerate(data.inputs()):
            loc.feed(event)
            if idle:
                loc.idle()
            if started_at is None and track_of(loc).filter is not None:
                started_at = i
        loc.flush()
        loc.finish()
        est = loc.estimate
        ends.append((est.lat, est.lon, started_at))
        loc.close()
    assert ends[0] == ends[1]
    east, north = data.frame.to_enu(ends[0][0], ends[0][1])
    assert np.hypot(east - data.emitter_enu[0], north - data.emitter_enu[1]) < 10.0
    assert ends[0][2] is not None and ends[0][2] < 0.8 * sum(1 for _ in data.inputs())  # started well before the end
