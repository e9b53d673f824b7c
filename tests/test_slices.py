"""Jobs in turns (slices.py): how many kernels a call's turn makes by their metered cost, a job's exception, a job
dropped unfinished, a check made in turns against the whole one, and a reproducible run that no idle call and no
clock can change."""
import gc
import logging
import threading

import numpy as np
import pytest
from conftest import track_of

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.inference import checks
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.scheduling import slices
from aoa_localizer.engine.scheduling.slices import SlicedJob
from aoa_localizer.simulation.evaluation import scenario_config
from aoa_localizer.simulation.scenarios import simulate

PIECE_COST = slices.Cost(0.0, 1.0)  # a kernel that charges its size in microseconds


@pytest.fixture
def stretch_us(monkeypatch):
    """The figures by hand take a stretch's own cost (STRETCH_US) as 120 us, whatever the fitted value says."""
    monkeypatch.setattr(slices, "STRETCH_US", 120.0)


@slices.metered(PIECE_COST, lambda made, i, cost_us: int(cost_us))
def _kernel(made: list[int], i: int, cost_us: float) -> None:
    made.append(i)


def counted(made: list[int], kernels: int, fail_at: int = -1, cost_us: float = 0.0):
    """A job of `kernels` kernel calls, each noted in `made` and charging `cost_us`; the one numbered `fail_at`
    raises instead."""
    def job() -> str:
        for i in range(kernels):
            if i == fail_at:
                raise ValueError("kernel failed")
            _kernel(made, i, cost_us)
        return "result"
    return job


@pytest.mark.parametrize(("cost_us", "per_call"), [(0.0, 41), (880.0, 4), (1880.0, 2), (2380.0, 1), (6000.0, 1)])
@pytest.mark.usefixtures("stretch_us")
def test_a_turn_makes_kernels_while_their_metered_cost_stays_under_the_call_budget(cost_us, per_call):
    """Stretches of (cost + STRETCH_US) each while the call's cost with one more stays under its budget, 5000 us
    here, by hand: 1000 us a stretch is 4 (a fifth would reach 5000); 2000 is 2; 2500 is 1; a stretch over the budget
    is one a call; free kernels cost STRETCH_US = 120 us each, 41 of them (4920 us: a 42nd would end at 5040)."""
    made: list[int] = []
    job = SlicedJob(counted(made, 100, cost_us=cost_us), 5000.0)
    job.advance()
    assert len(made) == per_call and not job.done()
    job.advance()
    assert len(made) == 2 * per_call
    assert job.result() == "result" and made == list(range(100)) and job.done()
    job.advance()  # nothing left to make
    assert made == list(range(100))


@pytest.mark.usefixtures("stretch_us")
def test_the_jobs_of_one_call_share_its_budget():
    """Inside one_call a second job gets what the first left (4000 of 5000 us spent: one stretch of 1000); outside,
    each its own."""
    first, second = [], []
    with slices.one_call():
        SlicedJob(counted(first, 60, cost_us=880.0), 5000.0).advance()
        SlicedJob(counted(second, 60, cost_us=880.0), 5000.0).advance()
    assert (len(first), len(second)) == (4, 1)
    first.clear()
    second.clear()
    SlicedJob(counted(first, 60, cost_us=880.0), 5000.0).advance()
    SlicedJob(counted(second, 60, cost_us=880.0), 5000.0).advance()
    assert (len(first), len(second)) == (4, 4)


@pytest.mark.usefixtures("stretch_us")
def test_the_filters_step_spends_the_calls_budget_before_the_job():
    """The step's metered cost counts: after a step that cost 2000 us, a job's stretches of 1000 us (880 metered
    and STRETCH_US) stop at the second, as a third would reach the 5000 us budget; after a step that cost more than
    the budget, still one, so a job never stalls behind dear steps."""
    for step_us, kernels in ((2000.0, 2), (12000.0, 1)):
        made: list[int] = []
        with slices.one_call(slices.Call()):
            slices.charge(slices.Cost(step_us, 0.0), 0)
            SlicedJob(counted(made, 60, cost_us=880.0), 5000.0).advance()
        assert len(made) == kernels, (step_us, made)


@pytest.mark.usefixtures("stretch_us")
def test_a_result_finished_after_half_the_budget_waits_for_the_next_point():
    """A job that ends once its call has spent half its budget (3 stretches of 1000 us: 3000 of 5000) is done only
    after release() (the track's next point), so applying it never adds to a full call, and idle time (which
    releases nothing) cannot change when a reproducible run applies it; one that ends cheaply (2 stretches, 2000
    us) is done at once."""
    for kernels, at_once in ((3, False), (2, True)):
        made: list[int] = []
        job = SlicedJob(counted(made, kernels, cost_us=880.0), 5000.0)
        job.advance()
        assert len(made) == kernels and job.done() is at_once
        job.advance()  # nothing left: still held
        assert job.done() is at_once
        job.release()
        assert job.done() and job.result() == "result"


def test_the_meter_charges_a_kernel_by_its_model():
    before = slices.spent_ns()
    slices.charge(slices.Cost(10.0, 0.5), 40)
    assert slices.metered_since(before) == 30.0


def test_a_declared_kernel_is_charged_by_its_arguments_after_the_call():
    """`metered` prices the elements its function reads from the call's arguments: 64 elements at 0.5 us and 10 us a
    call is 42 us; outside a job nothing else happens, and the kernel's value comes back as it was."""
    @slices.metered(slices.Cost(10.0, 0.5), lambda x: x.size)
    def doubled(x: np.ndarray) -> np.ndarray:
        return 2 * x

    before = slices.spent_ns()
    assert doubled(np.ones((8, 8))).sum() == 128.0
    assert slices.metered_since(before) == 42.0


def test_a_calls_cost_is_exact_whatever_the_thread_metered_before():
    """The meter counts integer nanoseconds: 2000 + 1500 + 1500 us is 5000 us exactly, also after 130,602.776 us of
    earlier work (in floats it came to 4999.99999999999, and a sweep budget's edge moved with the thread's past:
    the fast tier's flaky test_reproducible_sweeps_*)."""
    slices.charge(slices.Cost(130_602.776, 0.0), 0)
    with slices.one_call():
        call = slices.current_call()
        for us in (2000.0, 1500.0, 1500.0):
            slices.charge(slices.Cost(us, 0.0), 0)
        assert call.cost() == 5000.0


@pytest.mark.usefixtures("stretch_us")
def test_a_job_that_raises_ends_and_its_result_raises():
    made: list[int] = []
    job = SlicedJob(counted(made, 10, fail_at=3, cost_us=6000.0), 5000.0)  # one kernel a call
    for _ in range(3):
        job.advance()
    assert not job.done()
    job.advance()
    assert job.done() and made == [0, 1, 2]
    with pytest.raises(ValueError, match="kernel failed"):
        job.result()
    assert counted([], 4)() == "result"  # the same job is a plain function


@pytest.mark.usefixtures("stretch_us")
def test_a_job_dropped_unfinished_takes_its_thread_with_it():
    """A job left between its turns (a track re-started, a channel dropped) ends its thread when it is collected,
    with nothing more of it made."""
    made: list[int] = []
    job = SlicedJob(counted(made, 100, cost_us=6000.0), 5000.0)
    job.advance()
    thread = job._turns.thread
    assert thread is not None and thread.is_alive() and made == [0]
    del job
    gc.collect()
    thread.join(timeout=30.0)
    assert not thread.is_alive() and made == [0]


@pytest.mark.usefixtures("stretch_us")
def test_a_job_whose_thread_is_gone_fails_rather_than_waiting_forever():
    """A fork's child has none of its parent's threads: a job begun in the parent fails there (the track counts it
    and goes on) instead of handing its turn to a thread that no longer exists."""
    made: list[int] = []
    job = SlicedJob(counted(made, 100, cost_us=6000.0), 5000.0)
    job.advance()
    parked, gone = job._turns.thread, threading.Thread(target=lambda: None)
    gone.start()
    gone.join()
    job._turns.thread = gone  # what a forked child sees: a thread object whose thread does not run there
    job.advance()
    assert job.done() and made == [0]
    with pytest.raises(RuntimeError, match="thread is gone"):
        job.result()
    job._turns.cancel()  # the parent's own thread, still parked, ends
    parked.join(timeout=30.0)
    assert not parked.is_alive()


@pytest.mark.slow
def test_a_check_made_a_kernel_at_a_time_finds_what_the_whole_check_finds():
    """The same snapshot, checked whole and one kernel per call: the same noise, modes and points to the last bit."""
    data = simulate("urban", 1)
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=2)))
    for event in list(data.inputs())[:1500]:
        loc.feed(event)
    snap = track_of(loc).snapshot()
    whole = checks.run_check(snap)
    job = SlicedJob(lambda: checks.run_check(snap), 1.0)  # any kernel spends the budget
    turns = 0
    while not job.done():
        job.advance()
        job.release()
        turns += 1
    sliced = job.result()
    assert turns > 20  # many turns
    assert [m.mean.tolist() for m in sliced.modes] == [m.mean.tolist() for m in whole.modes]
    assert sliced.noise is not None and whole.noise is not None
    assert sliced.noise.k.tolist() == whole.noise.k.tolist()
    assert sliced.noise.reading_outlier_prob == whole.noise.reading_outlier_prob
    assert [p for p, _ in sliced.built] == [p for p, _ in whole.built]
    loc.close()


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["urban", "homing"])
def test_a_reproducible_run_is_the_same_with_idle_calls_between_inputs(scenario, caplog):
    """Jobs advance with the points alone: idle() between every input changes nothing, and the run finds the
    emitter (a job that never finished used to leave the start to the end of data)."""
    caplog.set_level(logging.ERROR, logger="aoa_localizer")  # (restored after the test: later ones read warnings)
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
        est = loc.view().estimate
        ends.append((est.lat, est.lon, started_at))
        loc.close()
    assert ends[0] == ends[1]
    east, north = data.frame.to_enu(ends[0][0], ends[0][1])
    assert np.hypot(east - data.emitter_enu[0], north - data.emitter_enu[1]) < 10.0
    assert ends[0][2] is not None and ends[0][2] < 0.8 * sum(1 for _ in data.inputs())  # started well before the end
