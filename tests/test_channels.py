"""Several emitters at once, keyed by the DF record's frequency (engine/channels.py)."""
import math

import numpy as np
import pytest

from aoa_localizer.engine.channels import DEFAULT, channel_id
from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.simulation.fleet import simulate_fleet
from aoa_localizer.simulation.scenarios import SCENARIOS, simulate

EMITTERS = {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0), 868.3e6: (1800.0, 200.0)}


def play(loc: Localizer, fleet, frequency=True):
    for kind, station, row in fleet.events():
        if kind == "fix":
            loc.add_fix(*row[:4], station=station)
        else:
            loc.add_bearing(*row[:3], station=station, frequency_hz=row[3] if frequency else math.nan)
    loc.flush()
    loc.finish()


@pytest.mark.slow
def test_three_emitters_heard_at_the_same_stamps_are_each_found():
    """A receiver's VFOs share one stamp: three records per stamp, one per carrier; each channel finds its
    emitter, every estimate names its channel and frequency, and nothing is refused as repeated."""
    fleet = simulate_fleet({"": SCENARIOS["seed"]}, EMITTERS, 0)
    estimates: list = []
    loc = Localizer(LocalizerConfig(seed=1), on_estimate=estimates.append)
    play(loc, fleet)
    assert "bearing_repeated" not in loc.view().rejected
    frame = loc.view().frame
    for f, truth in EMITTERS.items():
        channel = loc._channels.live[channel_id(f)]
        assert channel.frequency_hz == f and channel.estimate.channel == channel.id
        e, n = frame.to_enu(channel.estimate.lat, channel.estimate.lon)
        origin = fleet.scenario.datum
        assert (origin[0], origin[1]) == pytest.approx((frame.lat0, frame.lon0), abs=1e-9)
        assert math.hypot(e - truth[0], n - truth[1]) < 10.0
        assert channel.estimate.points_used == 60
    assert {est.channel for est in estimates} == {channel_id(f) for f in EMITTERS}
    assert loc._channels.default.estimate is None  # no record came without a frequency


@pytest.mark.slow
def test_records_without_a_frequency_behave_exactly_as_before():
    """Frequency 0 and NaN go to the default channel: the same estimates, bit for bit, as add_bearing without one."""
    data = simulate("seed", 2)
    runs = []
    for freq in (None, 0.0, math.nan):
        loc = Localizer(LocalizerConfig(seed=4))
        for kind, row in data.events():
            if kind == "fix":
                loc.add_fix(*row[:4])
            elif freq is None:
                loc.add_bearing(*row[:3])
            else:
                loc.add_bearing(*row[:3], frequency_hz=freq)
        loc.flush()
        est = loc.view().estimate
        runs.append((est.east, est.north, est.cov.tolist(), est.channel))
    assert runs[0] == runs[1] == runs[2] and runs[0][3] == DEFAULT


def test_the_tolerance_decides_which_records_share_a_channel():
    loc = Localizer(LocalizerConfig(channel_tolerance_hz=5000.0))
    loc.add_fix(0.0, 39.1, 117.2)
    loc.add_fix(1.0, 39.1, 117.2)
    loc.add_bearing(0.1, 10.0, 90.0, frequency_hz=100e6)
    loc.add_bearing(0.2, 10.0, 90.0, frequency_hz=100e6 + 4000)  # within 5 kHz of the channel's first frequency
    loc.add_bearing(0.3, 10.0, 90.0, frequency_hz=100e6 + 20000)  # a new channel
    assert sorted(loc._channels.live) == [DEFAULT, "f100000000", "f100020000"]
    assert len(loc._channels.live["f100000000"].builder("").readings) == 2


def test_more_channels_than_max_channels_are_refused_and_counted():
    loc = Localizer(LocalizerConfig(max_channels=2))
    loc.add_fix(0.0, 39.1, 117.2)
    loc.add_fix(1.0, 39.1, 117.2)
    for k, f in enumerate((1e8, 2e8, 3e8, 3e8, 1e8)):
        loc.add_bearing(0.1 + 0.01 * k, 10.0, 90.0, frequency_hz=f)
    assert loc.view().rejected["channel_limit"] == 2 and len(loc._channels.live) == 3  # the default one is not counted


@pytest.mark.parametrize("freq", [-1.0, math.inf, -math.inf])
def test_a_bad_frequency_is_refused_with_its_reason(freq):
    loc = Localizer()
    loc.add_fix(0.0, 39.1, 117.2)
    loc.add_fix(1.0, 39.1, 117.2)
    loc.add_bearing(0.5, 10.0, 90.0, frequency_hz=freq)
    assert loc.view().rejected["bad_frequency"] == 1 and list(loc._channels.live) == [DEFAULT]


@pytest.mark.slow
def test_a_silent_channel_is_retired_with_its_last_estimate_and_a_new_one_starts_fresh():
    """Emitter 446 MHz stops after half the drive; channel_timeout_s later it is retired (its estimate kept);
    when it comes back it starts a new track under the same id."""
    fleet = simulate_fleet({"": SCENARIOS["seed"]}, {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0)}, 1)
    rows = fleet.bearings[""]
    start, end = rows[0, 0], rows[-1, 0]
    quiet = start + 0.3 * (end - start), start + 0.7 * (end - start)
    gone = (rows[:, 3] == 446.0e6) & (rows[:, 0] > quiet[0]) & (rows[:, 0] < quiet[1])
    fleet.bearings[""] = rows[~gone]
    loc = Localizer(LocalizerConfig(seed=1, channel_timeout_s=0.2 * (end - start)))
    play(loc, fleet)
    retired = loc._channels.retired["f446000000"]
    assert retired.retired and retired.estimate is not None and retired.estimate.points_used >= 10
    back = loc._channels.live["f446000000"]
    assert back is not retired and back.track.points_seen < 60 - retired.track.points_seen
    assert [c.id for c in loc._channels.all()].count("f446000000") == 1  # the live one; the retired kept aside


@pytest.mark.slow
def test_the_json_line_carries_channel_and_frequency():
    loc = Localizer(LocalizerConfig(seed=1))
    fleet = simulate_fleet({"": SCENARIOS["seed"]}, {433.92e6: (1200.0, 800.0)}, 0)
    play(loc, fleet)
    line = loc.view().estimate.to_json_dict()
    assert line["channel"] == "f433920000" and line["frequency_hz"] == 433.92e6
    default = Localizer(LocalizerConfig(seed=1))
    play(default, fleet, frequency=False)
    line = default.view().estimate.to_json_dict()
    assert line["channel"] == "default" and line["frequency_hz"] is None


@pytest.mark.slow
def test_each_channel_draws_from_its_own_generator():
    """A channel's run depends on the seed and its id only, not on the other channels heard with it."""
    both = simulate_fleet({"": SCENARIOS["seed"]}, {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0)}, 0)
    alone = simulate_fleet({"": SCENARIOS["seed"]}, {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0)}, 0)
    alone.bearings[""] = alone.bearings[""][alone.bearings[""][:, 3] == 446.0e6]
    runs = []
    for fleet in (both, alone):
        loc = Localizer(LocalizerConfig(seed=3))
        play(loc, fleet)
        runs.append(loc._channels.live["f446000000"].estimate)
    assert np.array_equal(runs[0].particles, runs[1].particles)


@pytest.mark.slow
def test_channels_sharing_stamps_close_their_points_at_different_readings():
    """Five carriers of one scan (shared stamps, 20 Hz, a vehicle at 15 m/s): each channel's first point is cut
    shorter by its own share, so their points close at different readings instead of all in one scan (a burst of
    work); the first frequency channel's points are a single emitter's, and every later point is full size."""
    from aoa_localizer.engine.geodesy import LocalFrame
    frame = LocalFrame(39.1, 117.2, 5.0)
    loc = Localizer(LocalizerConfig(seed=1))
    freqs = [400e6 + 25e3 * k for k in range(5)]
    closes: dict[str, list] = {}
    for step in range(400):  # 20 s
        t = 0.05 * step
        if step % 2 == 0:
            lat, lon, alt = frame.to_geodetic(15.0 * t, 0.0)
            loc.add_fix(1e9 + t, float(lat), float(lon), float(alt))
        for f in freqs:
            loc.add_bearing(1e9 + t, 45.0, 80.0, frequency_hz=f)
        if step == 0:
            for channel in [c for c in loc._channels.live.values() if c.id != DEFAULT]:
                got = closes[channel.id] = []
                channel.track.add = lambda readings, real=channel.track.add, got=got: (
                    got.append((readings[0].stamp, len(readings))) or real(readings))
    sizes = {cid: [n for _, n in got] for cid, got in closes.items()}
    first = sizes[channel_id(freqs[0])]
    assert len(set(first)) == 1  # a single emitter's: every point full size (10 m at 15 m/s: 14 readings)
    assert len({s[0] for s in sizes.values()}) == 5 and all(set(s[1:]) == set(first) for s in sizes.values())
    starts = [stamp for got in closes.values() for stamp, _ in got[1:]]
    assert max(starts.count(s) for s in set(starts)) == 1  # no two channels close a point on the same reading


@pytest.mark.slow
def test_the_primary_channel_is_the_default_while_it_has_data_else_the_one_with_most_points():
    """emitter/pose's channel: none before an estimate; with records only on frequencies, the channel with the most
    points (one emitter heard on one frequency is the primary, as round 1's clients expect); the default channel
    as soon as it has an estimate. Here 446 MHz goes quiet after 40 % of its records, and the same emitter's
    last 40 % come without a frequency."""
    primaries: list = []
    loc = Localizer(LocalizerConfig(seed=1), on_estimate=lambda est: primaries.append((est.channel,
                                                                                        loc.view().primary)))
    assert loc.view().primary is None
    fleet = simulate_fleet({"": SCENARIOS["seed"]}, {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0)}, 0)
    events = list(fleet.events())
    quiet_records = sum(kind == "bearing" and row[3] == 446.0e6 for kind, _, row in events)
    seen = 0
    for kind, station, row in events:
        if kind == "fix":
            loc.add_fix(*row[:4], station=station)
        elif row[3] == 433.92e6:
            loc.add_bearing(*row[:3], station=station, frequency_hz=row[3])
        else:
            seen += 1
            if seen <= 0.4 * quiet_records:
                loc.add_bearing(*row[:3], station=station, frequency_hz=row[3])
            elif seen > 0.6 * quiet_records:
                loc.add_bearing(*row[:3], station=station)
    loc.flush()
    loc.finish()
    first_default = next(i for i, (channel, _) in enumerate(primaries) if channel == DEFAULT)
    busy, quiet = loc._channels.live["f433920000"], loc._channels.live["f446000000"]
    assert busy.track.points_used > quiet.track.points_used and quiet.estimate is not None
    assert primaries[first_default - 1][1] == busy.id
    assert all(primary == DEFAULT for _, primary in primaries[first_default:])
    assert loc._channels.primary() is loc._channels.default


@pytest.mark.slow
def test_two_localizers_split_the_spectrum_by_band_and_each_emitter_is_found_once():
    """`frequency_band_hz` (half-open [low, high)): two nodes sharing one receiver's records over adjacent bands
    localise every emitter exactly once, as one node does; each counts the other's records as `other_band`, not
    as refused, and a record without a frequency belongs to no band."""
    fleet = simulate_fleet({"": SCENARIOS["seed"]}, EMITTERS, 0)
    bands = ([400e6, 446.0e6], [446.0e6, 1e9])  # 446.0 MHz is on the edge: the second band's, not the first's
    found: dict[str, list] = {}
    for band in bands:
        loc = Localizer(LocalizerConfig(seed=1, frequency_band_hz=band))
        play(loc, fleet)
        assert not set(loc.view().rejected) - {"point_outlier"} and loc._channels.default.estimate is None  # (noise)
        refused = sum(loc.view().rejected.values())
        assert loc.view().other_band == sum(1 for kind, _, row in fleet.events() if kind == "bearing"
                                     and not band[0] <= row[3] < band[1])
        for channel in loc._channels.all():
            if channel.estimate is not None:
                found.setdefault(channel.id, []).append(channel.estimate)
        before = loc.view().other_band
        loc.add_bearing(1e9, 10.0, 50.0)  # no frequency: not in any band
        assert loc.view().other_band == before + 1
        assert sum(loc.view().rejected.values()) == refused
    assert sorted(found) == sorted(channel_id(f) for f in EMITTERS)
    for f, truth in EMITTERS.items():
        (est,) = found[channel_id(f)]  # exactly once
        e, n = LocalFrame(*fleet.scenario.datum).to_enu(est.lat, est.lon)
        assert math.hypot(e - truth[0], n - truth[1]) < 10.0


@pytest.mark.slow
def test_the_simulator_shows_two_cars_and_several_frequencies_without_hardware(cli):
    """`simulate --scenario pair` (two stations) and `--emitters F,E,N ...` (one channel per frequency): each
    emitter's estimate printed with its error, exit 0 when every one is inside 3 times its ellipse."""
    from aoa_localizer.tools.simulate import main as simulate_main

    pair = cli(simulate_main, "--scenario", "pair")
    assert pair.returncode == 0 and "stations car1, car2" in pair.stdout, pair.stdout + pair.stderr
    two = cli(simulate_main, "--emitters", "433.92e6,1200,800", "446e6,400,1100")
    assert two.returncode == 0, two.stdout + two.stderr
    for name in ("433.920 MHz", "446.000 MHz"):
        line = next(line for line in two.stdout.splitlines() if line.startswith(name))
        assert float(line.split("error ")[1].split(" m")[0]) < 10.0
    assert cli(simulate_main, "--emitters", "433e6,12").returncode == 2


@pytest.mark.slow
def test_records_refused_after_opening_their_channels_do_not_lock_a_new_emitter_out(caplog):
    """A scanning receiver before its first fix: 64 frequencies whose records are all refused leave no channel open,
    so a genuine new emitter afterwards is located, not refused as `channel_limit` for ever (with 64 empty channels
    it was); and no channel that was never heard is logged as retired ("silent for inf s")."""
    import logging

    loc = Localizer(LocalizerConfig(max_channels=64, datum_lat=39.1, datum_lon=117.2))
    frame = LocalFrame(39.1, 117.2)
    for k in range(64):
        loc.add_bearing(10.0 + 0.01 * k, 40.0, 90.0, frequency_hz=1e8 + 1e6 * k)  # before any fix
    assert loc.view().rejected["before_first_fix"] == 64 and list(loc._channels.live) == [DEFAULT]
    with caplog.at_level(logging.INFO, logger="aoa_localizer"):
        for t in range(20, 400):
            lat, lon, _ = frame.to_geodetic(5.0 * (t - 20), 0.0)
            loc.add_fix(float(t), lat, lon)
            loc.add_bearing(t + 0.5, math.degrees(math.atan2(1200.0 - 5.0 * (t - 19.5), 800.0)) % 360, 90.0,
                            frequency_hz=433.92e6)
    assert loc.view().rejected["channel_limit"] == 0
    assert loc._channels.live["f433920000"].estimate is not None
    assert "silent for inf s" not in caplog.text


def test_at_the_limit_a_record_retires_the_silent_channels_itself():
    """Every channel taken and silent for channel_timeout_s: the next record of a new frequency retires them and
    is heard; before, retiring waited for a record admitted, which at the limit never came."""
    loc = Localizer(LocalizerConfig(max_channels=2, channel_timeout_s=10.0, datum_lat=39.1, datum_lon=117.2))
    lat, lon, _ = LocalFrame(39.1, 117.2).to_geodetic(0.0, 0.0)
    for t in range(0, 40):
        loc.add_fix(float(t), lat, lon)
        if t in (1, 2):
            loc.add_bearing(t + 0.5, 40.0, 90.0, frequency_hz=1e8 * t)
    loc.add_bearing(35.5, 40.0, 90.0, frequency_hz=5e8)
    assert loc.view().rejected["channel_limit"] == 0
    assert set(loc._channels.live) == {DEFAULT, "f500000000"} and set(loc._channels.retired) == {"f100000000",
                                                                                             "f200000000"}
