"""The node's own diagnostics and path, without ROS: stale inputs, a filter that keeps restarting, the path."""
import math
import time
from collections import Counter

import pytest

from aoa_localizer.core.spec import ConfigError
from aoa_localizer.ros.node_health import RESTART_WINDOW_S, RESTARTS_FOR_ERROR, LatencyHistogram, NodeHealth
from aoa_localizer.ros.node_params import NODE_PARAMS
from aoa_localizer.ros.vehicle_path import VehiclePath


def test_inputs_silent_past_stale_after_are_named_with_how_long():
    health = NodeHealth(now=100.0, stale_after_s=5.0)
    assert health.stale(104.0) == []
    assert {key for key, _, _ in health.stale(106.0)} == {"df_stale", "gps_stale"}  # never seen since the start
    health.reading(106.0)
    health.valid_fix(107.0)
    assert health.stale(110.0) == []
    stale = health.stale(111.5)
    assert [key for key, _, _ in stale] == ["df_stale"] and "for 5.5 s" in stale[0][1]
    assert {key for key, _, _ in health.stale(112.5)} == {"df_stale", "gps_stale"}


def test_repeated_restarts_within_the_window_are_an_error_and_age_out():
    health = NodeHealth(now=0.0, stale_after_s=5.0)
    health.count_restarts(1.0, Counter(global_restart=1, alarm=7))  # an alarm alone restarts nothing
    health.count_restarts(2.0, Counter(global_restart=1, filter_diverged=1))
    assert health.restart_error() is None
    health.count_restarts(3.0, Counter(global_restart=1, filter_diverged=1, emitter_moved=1))
    value, words = health.restart_error()
    assert f"restarted {RESTARTS_FOR_ERROR} times" in words and words in value
    health.count_restarts(1.5 + RESTART_WINDOW_S, Counter(global_restart=1, filter_diverged=1, emitter_moved=1))
    assert health.restart_error() is None  # the first restart (t = 1) left the window
    health.count_restarts(62.0, Counter(filter_diverged=2))  # a new Localizer: its totals start again at 0
    assert len(health.restarts) == 4  # t = 2, 3 and the two new ones
    assert health.restart_error() is not None


def test_the_path_keeps_the_latest_fixes_and_reports_only_news():
    fixes = []
    path = VehiclePath(3, on_valid_fix=lambda: fixes.append(1))
    assert path.new_paths() == {}
    for k in range(5):
        path.on_fix(float(k), 10.0 * k, 0.0)
    assert path.new_paths() == {"": [(2.0, 20.0, 0.0), (3.0, 30.0, 0.0), (4.0, 40.0, 0.0)]} and len(fixes) == 5
    assert path.new_paths() == {}  # nothing new since
    path.on_fix(4.5, 7.0, 8.0, "car2")  # each station its own path
    assert path.new_paths() == {"car2": [(4.5, 7.0, 8.0)]}
    path.resize(1)
    path.on_fix(5.0, 50.0, 0.0)
    assert path.new_paths() == {"": [(5.0, 50.0, 0.0)]}
    path.resize(0)
    path.on_fix(6.0, 60.0, 0.0)
    assert path.new_paths() == {}  # path_length 0: not published


@pytest.mark.parametrize(
    "name, bad",
    [("map_frame", ""), ("map_frame", "my map"), ("input_reliability", "sometimes"), ("stale_after_s", 0.0),
     ("path_length", -1), ("hardware_id", 3)],
)
def test_node_parameters_refuse_values_outside_their_declaration(name, bad):
    spec = {p.name: p for p in NODE_PARAMS}[name]
    spec.spec.check(name, spec.default)
    with pytest.raises(ConfigError, match=name):
        spec.spec.check(name, bad)


def test_latency_percentiles_since_start_are_read_at_their_bins_upper_edge():
    hist = LatencyHistogram()
    assert hist.total == 0 and math.isnan(hist.percentile(99))
    hist.add([1.0] * 99)
    hist.add([1000.0])
    assert hist.total == 100
    assert hist.percentile(99) == pytest.approx(1.0) and hist.percentile(100) == pytest.approx(1000.0)
    hist.add([1.5] * 900)
    assert 1.5 <= hist.percentile(50) <= 1.5 * 10 ** (1 / 40)  # never below the true value, at most a bin above
    hist.add([1e9])
    assert hist.percentile(100) == math.inf


def test_overload_names_its_cause_and_the_refusals_it_made_and_holds_one_period():
    """Reliability III, item 7: a stalled node dropped real bearings as gps_gap and stayed OK."""
    from aoa_localizer.ros.node_health import Overload

    o = Overload()
    assert o.judge(None, Counter(low_quality=3), 0) is None  # kept up: nothing said, the counts noted
    words = o.judge("the node was held up: this diagnostics period lasted 6.0 s (1 s configured)",
                    Counter(low_quality=3, gps_gap=141), 20)
    assert words.startswith("the node was held up") and "refused meanwhile: 141 as gps_gap" in words
    assert "not a GPS fault" in words and "20 inputs never arrived" in words and "low_quality" not in words
    after = o.judge(None, Counter(low_quality=3, gps_gap=150), 20)  # the backlog's refusals: still the stall's
    assert after.startswith("just before: the node was held up") and "9 as gps_gap" in after
    assert o.judge(None, Counter(low_quality=3, gps_gap=160), 20) is None  # a period later: its own cause
    assert o.rejected == Counter(gps_gap=150) and o.lost == 20


def test_stamp_gaps_count_random_losses_of_a_regular_stream():
    """Item 8: the lost counts stayed 0 while 25 % and 43 % of the records never arrived (a KEEP_LAST history
    drops at the publisher, where the middleware reports nothing)."""
    import numpy as np

    from aoa_localizer.engine.ingest.input_guard import StampGaps

    rng = np.random.default_rng(0)
    for share in (0.25, 0.43):
        stamps = np.arange(4000) * 0.05 + rng.normal(0.0, 0.003, 4000)  # 20 Hz with jitter
        kept = stamps[rng.random(4000) >= share]
        gaps = StampGaps(factor=1.5)
        for t in kept:
            gaps.add(float(t))
        truly = 4000 - len(kept)
        assert abs(gaps.missing - truly) < 0.05 * truly, (share, gaps.missing, truly)


def test_messages_the_middleware_never_delivered_are_counted_from_their_numbers_and_said_as_overload():
    """Issue 69: with 250 channels as single records, 28 % of them were overwritten in the node's full input queue
    and /diagnostics said nothing (the middleware reports no such loss). Their publication numbers show it."""
    import time
    from types import SimpleNamespace

    from aoa_localizer.ros.node_monitor import NodeMonitor, SequenceGaps

    mon = NodeMonitor(time.monotonic(), 1e9, lambda: 1e9)
    loc = SimpleNamespace(rejected=Counter())
    for seq in range(1, 21):
        mon.arrived({"received_timestamp": 1, "publication_sequence_number": seq}, "/gps/fix")
    assert mon._overload(loc) is None  # every message taken: nothing said
    for seq in [s for s in range(1, 101) if s % 4]:  # a quarter of the DF records lost
        mon.arrived({"received_timestamp": 1, "publication_sequence_number": seq}, "/df/bearing")
    words = mon._overload(loc)
    assert words.startswith("24 input messages (24.2 % of the period's) never reached it"), words  # 4, 8 .. 96 of 99
    assert "input_queue_depth" in words and mon._missing() >= 24
    gaps = SequenceGaps()
    for seq in (1, 2, 5, 3, 9):  # a number that steps back: two publishers' numbers interleave
        gaps.add(seq)
    assert gaps.missing == 2 and gaps.several
    none = SequenceGaps()
    none.add(None)  # a middleware that does not number its messages
    assert none.missing == 0 and none.last is None


def test_a_quiet_node_ticks_slowly_and_an_input_makes_it_tick_fast_at_once():
    """The idle timer: IDLE_PERIOD_S while inputs or idle work came within QUIET_AFTER_S, QUIET_IDLE_PERIOD_S after;
    a change of period starts from now (the timer reset), and an input ends a quiet spell at once."""
    from types import SimpleNamespace

    from aoa_localizer.ros.node import (
        IDLE_PERIOD_S,
        QUIET_AFTER_S,
        QUIET_IDLE_PERIOD_S,
        LocalizerNode,
        quiet_idle_period,
    )

    assert quiet_idle_period(0.0) == quiet_idle_period(QUIET_AFTER_S - 1e-3) == IDLE_PERIOD_S
    assert quiet_idle_period(QUIET_AFTER_S) == QUIET_IDLE_PERIOD_S > IDLE_PERIOD_S
    resets: list[int] = []
    timer = SimpleNamespace(timer_period_ns=int(IDLE_PERIOD_S * 1e9), reset=lambda: resets.append(1))
    node = SimpleNamespace(last_active=time.monotonic(), idle_period=IDLE_PERIOD_S, idle_timer=timer)
    LocalizerNode._pace_idle(node, False)  # type: ignore[arg-type]  # just active: stays fast
    assert timer.timer_period_ns == int(IDLE_PERIOD_S * 1e9) and not resets
    node.last_active -= QUIET_AFTER_S
    LocalizerNode._pace_idle(node, False)  # type: ignore[arg-type]
    assert timer.timer_period_ns == int(QUIET_IDLE_PERIOD_S * 1e9) and resets == [1]
    LocalizerNode._pace_idle(node, False)  # type: ignore[arg-type]  # still quiet: nothing changes
    assert resets == [1]
    LocalizerNode._pace_idle(node, True)  # type: ignore[arg-type]  # an input
    assert timer.timer_period_ns == int(IDLE_PERIOD_S * 1e9) and resets == [1, 1]


def test_the_node_sheds_half_its_df_records_per_period_it_cannot_keep_up_and_takes_them_back_once_it_does():
    """Issue 69: a backlog grew unseen in the node's input queue. The rule (shedding.py): a period whose messages
    waited LAG_S (median) before they were taken, while the engine's calls filled SHED_LOAD of it, halves the share of
    DF records kept, down to KEEP_MIN; one without a wait (QUICK_S) and with the engine under RELIEF_LOAD doubles it
    back; between, it stays. A wait while the engine's work is light is not the engine's: not shed for."""
    from aoa_localizer.ros.shedding import KEEP_MIN, LAG_S, QUICK_S, RELIEF_LOAD, SHED_LOAD, Shedding

    s = Shedding()
    assert all(s.keeps() for _ in range(1000)) and s.judge(0.0, 0.9) is None  # busy, yet keeping up
    assert all(s.keeps() for _ in range(1000))
    assert s.judge(LAG_S, 0.9 * SHED_LOAD) is None and s.keep == 1.0  # waiting, but the engine is not the cause
    assert all(s.keeps() for _ in range(1000))
    words = s.judge(LAG_S, SHED_LOAD)
    assert s.keep == 0.5 and "kept with probability 0.5" in words and "0 of 1000 DF records shed" in words
    kept = sum(s.keeps() for _ in range(4000))
    assert 1800 < kept < 2200 and s.shed == 4000 - kept  # each record with probability 0.5 (seeded)
    assert f"{4000 - kept} of 4000 DF records shed" in s.judge(2 * LAG_S, 0.8)
    for _ in range(10):
        s.judge(2 * LAG_S, 0.8)
    assert s.keep == KEEP_MIN
    s.judge(0.5 * LAG_S, 0.8)  # no wait, the engine busy: it stays
    s.judge(2 * LAG_S, 0.4)  # waiting, the engine between the two: it stays
    assert s.keep == KEEP_MIN
    s.judge(0.0, 0.5 * RELIEF_LOAD)
    assert s.keep == 2 * KEEP_MIN
    s.judge(10.0, 0.5 * RELIEF_LOAD)  # waiting, but the engine idle: not its work; nor yet caught up
    s.judge(QUICK_S, 0.5 * RELIEF_LOAD)
    assert s.keep == 2 * KEEP_MIN
    s.judge(0.5 * QUICK_S, 0.5 * RELIEF_LOAD)
    assert s.keep == 4 * KEEP_MIN
    for _ in range(5):
        s.judge(0.0, 0.1)
    assert s.keep == 1.0 and s.judge(0.0, 0.1) is None
    off = Shedding(enabled=False)
    assert off.judge(10.0, 1.0) is None and all(off.keeps() for _ in range(100)) and off.shed == 0
    s.judge(10.0, 1.0)
    s.enable(False)
    assert s.keep == 1.0


def test_a_backlog_is_said_as_overload_with_the_share_kept():
    """Messages that waited before the node took them are a backlog the middleware never reports: overload, and
    the records kept from then on are said and counted in the values."""
    import time
    from types import SimpleNamespace

    from aoa_localizer.ros.node_monitor import NodeMonitor

    mon = NodeMonitor(time.monotonic(), 1e9, lambda: 1.0)
    loc = SimpleNamespace(rejected=Counter())
    waited = time.time_ns() - 2_000_000_000  # arrived 2 s ago
    for _ in range(10):
        mon.arrived({"received_timestamp": waited}, "/df/bearing")
    mon.period_start, mon.callback_s = time.perf_counter() - 1.0, [0.9]  # a period of 1 s, 0.9 s of it worked
    mon.engine_s = 0.8  # of which in the engine's calls
    words = mon._overload(loc)
    assert words is not None and "waited 2.0" in words and "kept with probability 0.5" in words
    fresh = NodeMonitor(time.monotonic(), 1e9, lambda: 1e9, shed=False)
    for _ in range(10):
        fresh.arrived({"received_timestamp": waited}, "/df/bearing")
    words = fresh._overload(loc)
    assert words is not None and "waited" in words and "shedding" not in words
