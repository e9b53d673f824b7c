"""DF records that reach the node before the fix that places them (ros/fix_wait.py): ROS orders no two topics, and
on a busy machine a replay's bearings came before their fixes, all refused (used 0 of 200)."""
from pathlib import Path
from types import SimpleNamespace

import pytest

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.ros.fix_wait import FixWait
from msgs_adapters.bag import read_bag

PAIR = {"car1": {"fix": "/car1/gps/fix", "bearing": "/car1/df/bearing"},
        "car2": {"fix": "/car2/gps/fix", "bearing": "/car2/df/bearing"}}


def rec(stamp):
    return SimpleNamespace(stamp=stamp)


def test_a_record_a_fix_covers_goes_at_once_and_one_ahead_waits_for_its_fix():
    fed = []
    wait = FixWait(lambda station, r: fed.append((station, r.stamp)))
    wait.bearing("a", rec(0.5), now=0.0)  # no fix yet: waits
    wait.fix("a", 1.0)
    assert fed == [("a", 0.5)]
    wait.bearing("a", rec(0.9), now=0.1)  # covered: at once
    wait.bearing("a", rec(1.5), now=0.2)  # ahead: waits
    wait.bearing("b", rec(1.5), now=0.2)  # another station's own queue
    wait.bearing("a", rec(1.2), now=0.3)  # behind a waiting one: waits too (a station's order is kept)
    assert fed == [("a", 0.5), ("a", 0.9)] and wait.count == 3
    wait.fix("a", 2.0)
    assert fed[2:] == [("a", 1.5), ("a", 1.2)] and wait.count == 1
    wait.due(now=1.0)
    assert wait.count == 1  # not yet WAIT_S
    wait.due(now=0.2 + wait.wait_s)
    assert fed[-1] == ("b", 1.5) and wait.count == 0 and wait.timed_out == 1


def test_parked_records_are_bounded_the_oldest_going_on():
    fed = []
    wait = FixWait(lambda station, r: fed.append(r.stamp), limit=3)
    for k in range(5):
        wait.bearing("a", rec(float(k)), now=float(k))
    assert fed == [0.0, 1.0] and wait.count == 3


@pytest.mark.slow
def test_a_burst_of_bearings_ahead_of_their_fixes_is_located_not_refused():
    """The two-car sample bag with each station's bearings delivered up to 150 messages before the fixes that
    place them: straight to the engine, every bearing was refused (before_first_fix, gps_gap) and there was no
    estimate; through the node's wait, the same answer as in order."""
    bag = Path(__file__).resolve().parent.parent / "bags" / "pair"
    events = [e for e in read_bag(bag, {}, PAIR) if e.kind in ("fix", "bearing")]
    fixes, bearings = [e for e in events if e.kind == "fix"], [e for e in events if e.kind == "bearing"]
    skewed, f = [], 0
    for i, b in enumerate(bearings):
        skewed.append(b)
        while f < len(fixes) and fixes[f].record.stamp <= bearings[max(0, i - 150)].record.stamp:
            skewed.append(fixes[f])
            f += 1
    skewed += fixes[f:]
    results = {}
    for name, order, through_wait in (("in order", events, False), ("skewed", skewed, False),
                                      ("skewed, waited", skewed, True)):
        loc = Localizer(LocalizerConfig(seed=1))
        wait = FixWait(lambda station, r, loc=loc: loc.add_bearing(r.stamp, r.azimuth_deg, r.quality,
                                                                    station=station))
        for e in order:
            if e.kind == "fix":
                r = e.record
                loc.add_fix(r.stamp, r.lat, r.lon, r.alt, r.status, station=e.station)
                if through_wait:
                    wait.fix(e.station, r.stamp)
            elif through_wait:
                wait.bearing(e.station, e.record, now=0.0)
            else:
                loc.add_bearing(e.record.stamp, e.record.azimuth_deg, e.record.quality, station=e.station)
        loc.flush()
        results[name] = (loc.view().estimate, dict(loc.view().rejected))
        loc.close()
    assert results["skewed"][0] is None and results["skewed"][1].get("gps_gap", 0) > 0
    (done, refused), (base, _) = results["skewed, waited"], results["in order"]
    assert done is not None and not refused.get("gps_gap") and not refused.get("before_first_fix")
    assert (done.east, done.north) == (base.east, base.north)
