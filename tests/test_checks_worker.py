"""`scheduling: realtime`: global checks and start searches in the worker process (engine/inference/checks.py,
scheduling/worker.py), move sweeps spread over the points after a resampling (filters/resample_move.py)."""
import multiprocessing
import os
import pickle
from concurrent.futures import wait

import numpy as np
import pytest
from conftest import track_of

from aoa_localizer.core.spec import ConfigError
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.inference import checks
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.points.preprocess import columns
from aoa_localizer.engine.scheduling import worker as worker_module
from aoa_localizer.engine.track import initiator as initiator_module
from aoa_localizer.engine.track import supervisor as supervisor_module
from aoa_localizer.engine.track.initiator import Outcome
from aoa_localizer.simulation.evaluation import scenario_config
from aoa_localizer.simulation.scenarios import simulate


def settle_starts(loc: Localizer):
    """Wait for a start search (not for a global check)."""
    job = track_of(loc).job
    if job is not None and job.is_start:
        wait([job.future], timeout=60)


def play(loc: Localizer, data, paced=True):
    for event in data.inputs():
        loc.feed(event)
        if paced:
            loc.catch_up()
    loc.flush()
    return loc.finish()


def error_and_nees(loc: Localizer, data) -> tuple[float, float]:
    """Error and NEES of the final estimate in the scenario's frame (the Localizer's datum is a noisy first fix)."""
    est = loc.view().estimate
    east, north = LocalFrame(*data.scenario.datum).to_enu(est.lat, est.lon)
    d = np.array([east - data.scenario.emitter[0], north - data.scenario.emitter[1]])
    return float(np.hypot(*d)), float(d @ np.linalg.solve(est.cov, d))


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["seed", "urban"])
def test_realtime_scheduling_finds_the_emitter_as_reproducible_does_and_makes_the_sweeps_between_points(scenario):
    """The same data through both (realtime paced by catch_up(), as a receiver would): the worker's results are
    applied one point later and the move sweeps spread, so the runs differ, but both find the emitter (urban: 15 %
    wild bearings) with an ellipse that holds it, the start and the calibrations happen, and nothing is refused
    as an internal error. The node's idle time (catch_up between messages) makes the sweeps a resampling owes:
    the points then carry almost none, and every owed sweep is made."""
    data = simulate(scenario, 2)
    inline = Localizer(scenario_config(data, LocalizerConfig(seed=3, scheduling="reproducible")))
    play(inline, data)
    assert inline.view().estimate is not None and inline.view().events["recalibrated"] >= 2
    assert "internal_error" not in inline.view().rejected
    inline_err, _ = error_and_nees(inline, data)
    inline.close()
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=3, scheduling="realtime")))
    between = at_points = check_moves = 0

    def debt():
        return loc._scheduler.debt(track_of(loc).filter)

    for event in data.inputs():
        owed = debt().sweeps
        loc.feed(event)
        at_points += max(0, owed - debt().sweeps)  # sweeps a point made (a resampling adds to the debt)
        check_moves += debt().modes  # a worker's check applied: its move on the modes is owed too
        between += loc.catch_up()
        assert not debt().modes
    assert loc.catch_up() == 0 and loc._scheduler.owed(track_of(loc).filter) == 0  # nothing left owed
    assert between >= 20 and at_points <= between // 10 and check_moves >= 1  # one scheduled check in these runs
    loc.flush()
    loc.finish()
    assert loc.view().estimate is not None and loc.view().events["recalibrated"] >= 2
    assert "internal_error" not in loc.view().rejected
    worker_err, worker_nees = error_and_nees(loc, data)
    loc.close()
    assert worker_err < max(3.0, 2.0 * inline_err)  # a trial run: seed 1.2 vs 1.2 m, urban 9.8 vs 10.1 m
    assert worker_nees < 13.8  # inside the 99.9 % ellipse
    assert Localizer(LocalizerConfig(seed=3)).catch_up() == 0  # reproducible: nothing is ever owed


@pytest.mark.slow
def test_the_default_is_reproducible_from_python_and_realtime_in_the_node():
    assert not Localizer(LocalizerConfig())._scheduler.realtime
    live = Localizer(LocalizerConfig(seed=3), live=True)
    assert live._scheduler.realtime
    play(live, simulate("seed", 2))
    assert track_of(live).running.deferred
    live.close()
    assert not Localizer(LocalizerConfig(scheduling="reproducible"), live=True)._scheduler.realtime
    with pytest.raises(ConfigError, match="scheduling"):
        LocalizerConfig(scheduling="off")  # YAML would read an on/off choice as a boolean: not offered


@pytest.mark.slow
def test_finish_waits_for_the_worker_and_starts_if_it_lagged():
    """Data fed far faster than the worker runs (a script, not a receiver): finish() applies what is still running,
    tries the start the worker lagged behind, and the final global check runs: an estimate at end of data."""
    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    final = play(loc, data, paced=False)
    assert final is not None and final.end_of_data
    err, nees = error_and_nees(loc, data)
    assert err < 5.0 and nees < 13.8
    assert track_of(loc).job is None
    loc.close()


def check_failing_in_the_worker(snap):
    """run_check, but failing in the worker process (a module function: the job crosses to the process by name)."""
    if multiprocessing.parent_process() is not None:
        raise FloatingPointError("a bug in a search")
    return checks.run_check(snap)  # the end-of-data check runs inline


def search_killing_the_worker(*args):
    """search_start, but its worker process dies (a crash in a C library, an out-of-memory kill)."""
    if multiprocessing.parent_process() is not None:
        os._exit(1)
    return checks.search_start(*args)


@pytest.mark.slow
def test_a_worker_that_keeps_dying_is_given_up_after_three_and_the_work_goes_inline(monkeypatch, caplog):
    """Each dead worker costs its job (counted internal_error, the first logged with its traceback); after three in
    a row the worker is given up with one warning and the checks run in the calls: the emitter is still found."""
    monkeypatch.setattr(initiator_module, "search_start", search_killing_the_worker)
    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    play(loc, data)
    assert loc._scheduler.worker.unusable == "its process died 3 times in a row"
    assert loc.view().rejected["internal_error"] == 3 and track_of(loc).filter is not None  # started inline
    said = [r for r in caplog.records if r.exc_info]
    assert len(said) == 1  # one traceback, not one per job
    err, nees = error_and_nees(loc, data)
    assert err < 5.0 and nees < 13.8


@pytest.mark.slow
def test_data_fed_faster_than_the_worker_searches_starts_from_a_fresh_search():
    """Points arriving far faster than the start searches (a bag replayed at full speed, no finish: a live node):
    a search over a few points is no start for the many held by the time it ends, so it is run again; idle()
    applies the last one once the data pauses. The start is honest: the ellipse holds the emitter."""
    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    for event in data.inputs():
        loc.feed(event)
    made = []
    for _ in range(20):  # the data has ended: each idle() applies a finished search or starts a new one
        loc.catch_up()
        made += loc.idle()
        if track_of(loc).filter is not None and track_of(loc).job is None:
            break
    assert made and loc.view().estimate is made[-1]
    err, nees = error_and_nees(loc, data)
    assert err < 5.0 and nees < 13.8
    assert loc.view().estimate.points_used >= 50  # started from (nearly) all 60 points, not the first search's 10
    loc.close()


@pytest.mark.slow
def test_a_failing_check_is_counted_and_the_track_goes_on(monkeypatch):
    monkeypatch.setattr(supervisor_module, "run_check", check_failing_in_the_worker)
    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    play(loc, data)
    assert loc.view().rejected["internal_error"] >= 1
    err, _ = error_and_nees(loc, data)
    assert loc.view().track.points_used == 60 and err < 5.0  # every point still used, the emitter still found
    loc.close()


@pytest.mark.slow
def test_a_worker_that_cannot_start_leaves_the_work_inline_and_says_so_once(monkeypatch, caplog):
    """A worker process that cannot start (no processes allowed; a script's unguarded main under spawn): each job
    runs in the call, as reproducible, the worker is not tried again and one warning says why."""
    starts = []

    def cannot_start(*args, **kwargs):
        starts.append(1)
        raise OSError("cannot start a process")

    monkeypatch.setattr(worker_module, "ProcessPoolExecutor", cannot_start)
    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    play(loc, data, paced=False)
    err, nees = error_and_nees(loc, data)
    assert track_of(loc).job is None and loc.view().events["recalibrated"] >= 2
    assert err < 5.0 and nees < 13.8 and "internal_error" not in loc.view().rejected
    assert len(starts) == 1 and loc._scheduler.worker.unusable == "cannot start a process"
    said = [r.getMessage() for r in caplog.records if "check worker is given up" in r.getMessage()]
    assert len(said) == 1 and "__main__" in said[0]


def realtime_run_in_a_pool_worker(r: int) -> tuple[str, float]:
    """A realtime Localizer inside a multiprocessing.Pool's (daemonic) worker: why its check worker was given up,
    and the final error (a module function: the pool calls it by name)."""
    data = simulate("seed", r)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    play(loc, data, paced=False)
    return loc._scheduler.worker.unusable, error_and_nees(loc, data)[0]


@pytest.mark.slow
def test_a_realtime_localizer_in_a_daemonic_process_runs_its_checks_inline():
    """multiprocessing forbids a Pool's worker to have children: the check worker is given up, the work inline."""
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        why, err = pool.apply(realtime_run_in_a_pool_worker, (2,))
    assert "daemonic" in why and err < 5.0


@pytest.mark.slow
def test_a_check_for_a_filter_since_replaced_is_dropped():
    """A check submitted for one filter is not applied to the filter that replaced it (divergence, re-start): its
    snapshot is of points the new filter never saw. Results are applied only at a point, so the job's timing
    does not matter."""
    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    events = list(data.events())
    i = 0
    while track_of(loc).job is None or track_of(loc).job.is_start:  # until a global check is running
        kind, row = events[i]
        loc.add_fix(*row[:4]) if kind == "fix" else loc.add_bearing(*row[:3])
        settle_starts(loc)
        i += 1
    track = track_of(loc)
    track._diverged()  # what a non-finite cloud does: the filter is dropped, the track re-starts from new bearings
    wait([track.job.future], timeout=60)
    calibrations = track.events["recalibrated"]
    points = track.points_seen
    while track.points_seen == points:  # to the next point, where a result would be applied
        kind, row = events[i]
        loc.add_fix(*row[:4]) if kind == "fix" else loc.add_bearing(*row[:3])
        i += 1
    assert track.job is None and track.events["recalibrated"] == calibrations  # dropped
    for kind, row in events[i:]:
        loc.add_fix(*row[:4]) if kind == "fix" else loc.add_bearing(*row[:3])
        loc.catch_up()
    assert loc.view().rejected["filter_diverged"] == 1 and "internal_error" not in loc.view().rejected
    assert track.filter is not None and len(track.window) < track.points_seen  # re-started after the drop
    loc.close()


@pytest.mark.slow
def test_a_snapshot_crosses_to_the_worker_process_whole():
    """Pickled (packed readings), a snapshot gives the worker the same points and the same check result."""
    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3))
    play(loc, data)
    snap = track_of(loc).snapshot()
    copy = pickle.loads(pickle.dumps(snap))
    assert len(copy.groups) == len(snap.groups) == 60
    for g, h in zip(snap.groups, copy.groups, strict=True):
        assert all(np.array_equal(a, b) for a, b in zip(columns(g), columns(h), strict=True))
    here, there = checks.run_check(snap), checks.run_check(copy)
    assert np.allclose(here.modes[0].mean, there.modes[0].mean, rtol=0, atol=1e-9)
    for (a, keep_a), (b, keep_b) in zip(here.built, there.built, strict=True):  # to rounding (packed arrays)
        assert np.allclose([a.east, a.north, a.theta, a.sigma], [b.east, b.north, b.theta, b.sigma], rtol=1e-12)
        assert np.array_equal(keep_a, keep_b)


@pytest.mark.slow
def test_the_worker_and_the_resource_tracker_die_with_a_killed_parent(tmp_path):
    """Reliability III, item 9: a node killed by SIGKILL (the OOM killer) left its check worker and
    multiprocessing's resource tracker (~150 MB) running; a supervisor that respawned the node piled them up."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "parent.py"
    script.write_text(
        "import math, multiprocessing.resource_tracker as rt, time\n"
        "from aoa_localizer.engine.scheduling.worker import CheckWorker\n"
        "if __name__ == '__main__':\n"
        "    w = CheckWorker()\n"
        "    w.submit(math.pi.__float__).result(60)\n"
        "    print(*w._pool._processes, rt._resource_tracker._pid, flush=True)\n"
        "    time.sleep(120)\n")
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        children = [int(pid) for pid in parent.stdout.readline().split()]
        assert len(children) == 2 and all(alive(pid) for pid in children)
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(10)
        end = time.monotonic() + 10
        while any(alive(pid) for pid in children) and time.monotonic() < end:
            time.sleep(0.1)
        assert not any(alive(pid) for pid in children)
    finally:
        if parent.poll() is None:
            parent.kill()


def alive(pid: int) -> bool:
    """A process that runs (a zombie waiting for its reaper counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except FileNotFoundError:
        return False


def test_a_start_search_stale_twice_is_used_rather_than_searched_forever(monkeypatch):
    """With hundreds of channels queued behind one worker every start search comes back stale (more points than it
    searched): searching again each time never started a filter (the node under 250 carriers published nothing in
    two minutes). One stale result is searched again; a second is used, its modes proposing for every point held."""
    from concurrent.futures import Future

    from aoa_localizer.engine.inference.checks import search_start

    data = simulate("seed", 2)
    loc = Localizer(LocalizerConfig(seed=3, scheduling="realtime"))
    monkeypatch.setattr(loc._scheduler.worker, "submit", lambda job: Future())  # a worker that never answers
    snap = None
    for event in data.inputs():
        loc.feed(event)
        t = loc._channels.default.track
        if snap is None and len(t.window) == 20:
            snap = t.snapshot()
    assert snap is not None and t.filter is None and len(t.window) >= 40
    res = search_start(snap, initiator_module.MIN_INLIERS, initiator_module.MAX_ELLIPSE_RANGE_SHARE)
    assert res.determined and res.searched == 20
    held = len(t.window)
    assert t.initiator.outcome(res, held) is Outcome.SEARCH_AGAIN  # stale: searched again, at once
    assert t.initiator.search_due(held, searching=False)
    assert t.initiator.outcome(res, held) is Outcome.START  # stale again: used
    loc.close()


@pytest.mark.slow
def test_a_checks_modes_are_scored_on_the_filters_own_posterior():
    """The end of data's check over every point: its best mode's log posterior is the track's own at that place (the
    radio-range prior included), so the re-start test compares the modes and the particles on one posterior."""
    from aoa_localizer.engine.inference.global_search import log_posterior

    data = simulate("seed", 1)
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=1)))
    play(loc, data)
    loc.flush()
    loc.finish()
    t = track_of(loc)
    assert t.filter is not None and t.robust().reach is not None
    best = t.modes[0]
    assert best.log_post == pytest.approx(float(log_posterior(best.mean, t.points(), t.robust())), abs=1e-6)
    loc.close()


@pytest.mark.slow
def test_a_count_that_finishes_after_the_last_point_is_published_between_inputs():
    """A live node's data end with no finish: a transmitter count still under way at the last point is work
    (`working`, what the launcher waits for before its verdict), and idle() adopts it when it ends and publishes the
    estimate it changes, rather than holding it for a point that may never come."""
    from dataclasses import replace

    from aoa_localizer.simulation.scenarios import SCENARIOS

    data = simulate(replace(SCENARIOS["seed"], co_channel=((600.0, 1300.0),), co_shares=(0.5, 0.5)), 1)
    loc = Localizer(LocalizerConfig(seed=1, scheduling="realtime"))
    for event in data.inputs():  # faster than the worker counts: a bag replayed at full speed
        loc.feed(event)
    made = []
    for _ in range(50):
        loc.catch_up()
        made += loc.idle()
        if not loc.view().track.working:
            break
    assert not loc.view().track.working
    assert made and loc.view().estimate is made[-1] and loc.view().estimate.transmitter_count == 2
    loc.close()
