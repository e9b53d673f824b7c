"""Reliability III: a hostile record costs at most itself (a future stamp on another channel, an absurd
frequency, a stream of distinct frequencies), each reproduced as the review did it, then passing."""
import re

import pytest
from conftest import track_of

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.channels import FREQUENCY_MAX_HZ, channel_id
from aoa_localizer.simulation.scenarios import simulate


def feed_with(extra, at_share=1 / 3):
    """`seed` run 0 into a fresh Localizer, `extra(loc, t)` called once a third of the way in (t: that event's
    stamp); the Localizer after flush()."""
    data = simulate("seed", 0)
    loc = Localizer(LocalizerConfig(seed=1))
    events = list(data.events())
    for i, (kind, row) in enumerate(events):
        if i == int(len(events) * at_share):
            extra(loc, row[0])
        if kind == "fix":
            loc.add_fix(row[0], *row[1:4])
        else:
            loc.add_bearing(row[0], *row[1:3])
    loc.flush()
    return loc


@pytest.mark.slow
@pytest.mark.parametrize(("ahead_s", "reason"), [(1e9, "bearing_stamp_jump"), (200.0, "gps_gap")])
def test_one_future_record_on_another_channel_costs_only_itself(ahead_s, reason):
    """Item 1: a record 1e9 s ahead at 1 MHz used to drop 201 of the 300 genuine bearings as gps_gap (the station's
    newest DF stamp was the maximum over its channels, and a new channel takes any first stamp); 200 s ahead,
    inside max_stamp_jump_s, dropped 141. Now the first is refused on arrival, the second waits for a fix."""
    clean = feed_with(lambda loc, t: None)
    loc = feed_with(lambda loc, t: loc.add_bearing(t + ahead_s, 10.0, 90.0, frequency_hz=1e6))
    assert clean.view().track.bearings_used == 300 and not clean.view().rejected
    assert loc.view().track.bearings_used == 300
    assert dict(loc.view().rejected) == {reason: 1}


def test_a_new_channel_of_a_sparse_station_may_start_after_a_long_gap():
    """A survey's bearings are minutes apart: a new frequency an hour after the last record is not a clock glitch."""
    loc = Localizer(LocalizerConfig(datum_lat=39.1, datum_lon=117.2))
    for k in range(3):
        loc.add_fix(600.0 * k, 39.1, 117.2 + 0.001 * k)
        loc.add_bearing(600.0 * k + 0.5, 45.0 + 5 * k, 90.0, frequency_hz=433e6)
    loc.add_bearing(5400.0, 45.0, 90.0, frequency_hz=446e6)
    assert "bearing_stamp_jump" not in loc.view().rejected


@pytest.mark.parametrize("frequency", [1e300, FREQUENCY_MAX_HZ * 1.01, -1.0, float("inf")])
def test_a_frequency_no_receiver_reports_is_refused(frequency):
    """Item 2: vector.z = 1e300 made a channel whose topic name ROS refuses (the node crashed, rc 1)."""
    loc = Localizer(LocalizerConfig())
    assert loc.add_bearing(1.0, 10.0, 90.0, frequency_hz=frequency) is None
    assert dict(loc.view().rejected) == {"bad_frequency": 1}


def test_every_channel_id_is_a_short_valid_ros_name_token():
    for f in (1e-3, 1.0, 433.92e6, 2.4e9, FREQUENCY_MAX_HZ):
        cid = channel_id(f)
        assert re.fullmatch(r"f[0-9]{1,13}", cid), cid


def test_memory_of_heard_frequencies_is_bounded():
    """Item 12: +71 MB per million jittered frequencies (one dict entry each, for ever)."""
    loc = Localizer(LocalizerConfig(channel_tolerance_hz=1e6))
    loc.add_fix(0.0, 39.1, 117.2)  # the records are admitted (a channel no record was admitted on is closed)
    loc.add_fix(0.5, 39.1, 117.2)
    for k in range(20_000):
        loc.add_bearing(1.0 + k * 1e-3, 10.0, 90.0, frequency_hz=433e6 + k * 1e-3)
    assert len(loc._channels._heard) <= 4096
    assert len(loc._channels.live) == 2  # the default channel and 433 MHz: the jitter is within the tolerance


@pytest.mark.parametrize(("name", "value"), [
    ("afsa.try_number", 10**9),  # MemoryError, rc 1
    ("afsa.max_iterations", 10**9),  # 100 % CPU, no diagnostics, SIGINT ignored
    ("gfapf.iterations", 10**9),
    ("de.generations", 10**9),
    ("df_time_offset_s", -1e308),  # every bearing then refused as bearing_repeated
    ("gps_max_gap_s", 1e308),
    ("obs_max_duration_s", 1e-300),
    ("init_max_points", 2**62),
])
def test_parameter_values_that_crashed_or_stalled_the_node_are_refused(name, value):
    """Item 5: each passed validation before."""
    from aoa_localizer.core.spec import ConfigError

    with pytest.raises(ConfigError, match=name.replace(".", r"\.")):
        LocalizerConfig().with_changes(**{name: value})


def test_every_numeric_parameter_has_a_range_on_both_sides():
    from aoa_localizer.engine.config import parameter_specs
    from aoa_localizer.ros.node_params import NODE_PARAMS

    open_ended = [p.name for p in parameter_specs() + list(NODE_PARAMS)
                  if p.spec.kind in (int, float) and (p.spec.low is None or p.spec.high is None)]
    assert open_ended == ["seed"]  # any non-negative integer seeds numpy's generator


@pytest.mark.slow
def test_a_filter_update_out_of_memory_skips_the_point_and_keeps_the_state(monkeypatch):
    """Item 5: the update's except did not cover MemoryError (the node exited 1)."""
    data = simulate("seed", 0)
    loc = Localizer(LocalizerConfig(seed=1))
    events = list(data.events())
    half = len(events) // 2
    for kind, row in events[:half]:
        loc.add_fix(row[0], *row[1:4]) if kind == "fix" else loc.add_bearing(row[0], *row[1:3])
    f = track_of(loc).running

    def no_memory(point):
        raise MemoryError

    monkeypatch.setattr(f, "update", no_memory)
    for kind, row in events[half:half + 40]:
        loc.add_fix(row[0], *row[1:4]) if kind == "fix" else loc.add_bearing(row[0], *row[1:3])
    assert loc.view().rejected["internal_error"] >= 1 and loc.view().estimate is not None


def test_retired_channels_are_bounded_under_ever_new_frequencies():
    """Item 12: every channel ever retired was kept, with its particles, for good."""
    loc = Localizer(LocalizerConfig(max_channels=4, channel_timeout_s=5.0))
    for k in range(60):  # a new frequency every 10 s: each retires while the next ones come
        for j in range(3):
            loc.add_bearing(10.0 * k + j, 10.0, 90.0, frequency_hz=100e6 + 1e6 * k)
    assert len(loc._channels.retired) <= 4 and len(loc._channels.live) <= 5
    assert len(loc._channels.all()) <= 9
