"""Several DF stations fused: moving vehicles with their own GPS tracks, and fixed sites (engine/ingest/station.py)."""
import math

import numpy as np
import pytest
from pymap3d import vincenty

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import ellipse_axes
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.simulation.fleet import PAIR, simulate_fleet

TRUTH = (1200.0, 800.0)


def run(fleet, only=None, loc=None):
    loc = loc or Localizer(LocalizerConfig(seed=1))
    for kind, station, row in fleet.events():
        if only is not None and station not in only:
            continue
        if kind == "fix":
            loc.add_fix(*row[:4], station=station)
        else:
            loc.add_bearing(*row[:3], station=station)
    loc.flush()
    loc.finish()
    return loc


def error(loc, fleet) -> float:
    e, n = LocalFrame(*fleet.scenario.datum).to_enu(loc.view().estimate.lat, loc.view().estimate.lon)
    return math.hypot(e - TRUTH[0], n - TRUTH[1])


@pytest.mark.slow
def test_two_vehicles_fix_the_emitter_better_than_either_alone():
    """Each car sees the emitter over a narrow span of directions; their bearings cross at wide angles."""
    fleet = simulate_fleet(PAIR, {0.0: TRUTH}, 0)
    alone = [run(fleet, [name]) for name in PAIR]
    both = run(fleet)
    assert both.view().estimate.points_used == sum(a.view().estimate.points_used for a in alone) == 40
    assert "bearing_repeated" not in both.view().rejected  # the two receivers' stamps coincide; each has its own clock
    major = [ellipse_axes(loc.view().estimate.cov)[0] for loc in alone]
    assert ellipse_axes(both.view().estimate.cov)[0] < 0.7 * min(major)
    assert error(both, fleet) < 10.0
    assert set(both.view().stations) == set(PAIR)


def site_bearings(frame: LocalFrame, site_enu, stamps, sigma_deg, rng) -> np.ndarray:
    s_lat, s_lon, _ = frame.to_geodetic(*site_enu)
    e_lat, e_lon, _ = frame.to_geodetic(*TRUTH)
    _, az = vincenty.vdist(s_lat, s_lon, e_lat, e_lon)
    return float(az) + sigma_deg * rng.standard_normal(len(stamps))


@pytest.mark.slow
def test_a_fixed_site_gives_its_position_once_and_bearings_for_hours():
    """A site declared at a position sends a bearing a minute for three hours, never a fix: every one is used,
    and with one car's short drive the emitter is fixed far better than by the car alone."""
    fleet = simulate_fleet({"car1": PAIR["car1"]}, {0.0: TRUTH}, 0)
    frame = LocalFrame(*fleet.scenario.datum)
    site = (2500.0, 0.0)  # across the car's long axis
    stamps = np.arange(5.0, 3 * 3600.0, 60.0)
    az = site_bearings(frame, site, stamps, 0.5, np.random.default_rng(0))
    loc = Localizer(LocalizerConfig(seed=1))
    lat, lon, _ = frame.to_geodetic(*site)
    assert loc.add_station("site", fixed=True, position=(lat, lon))
    events = [(t, "bearing", "site", (t, a, 90.0, 0.0)) for t, a in zip(stamps, az, strict=True)]
    events += [(row[0], kind, name, row) for kind, name, row in fleet.events()]
    for _, kind, name, row in sorted(events, key=lambda e: e[0]):
        if kind == "fix":
            loc.add_fix(*row[:4], station=name)
        else:
            loc.add_bearing(*row[:3], station=name, frequency_hz=row[3])
    loc.flush()
    assert not loc.view().rejected, loc.view().rejected
    car = run(fleet)
    assert loc.view().estimate.bearings_used == car.view().estimate.bearings_used + len(stamps)
    assert ellipse_axes(loc.view().estimate.cov)[0] < 0.5 * ellipse_axes(car.view().estimate.cov)[0]
    assert error(loc, fleet) < 10.0
    assert loc.view().frame == LocalFrame(lat, lon, 0.0)  # the site's position set the datum: it came first


def test_a_fixed_station_takes_its_position_from_a_single_fix_and_keeps_a_configured_one_across_reset():
    loc = Localizer()
    loc.add_station("mast", fixed=True)
    loc.add_bearing(1.0, 45.0, 90.0, station="mast")
    assert loc.view().rejected["before_first_fix"] == 1
    loc.add_fix(2.0, 39.1, 117.2, station="mast")  # one fix: no confirmation needed for a site, no track either
    loc.add_bearing(250.0, 45.0, 90.0, station="mast")  # long after the fix: still placed at the site
    assert len(loc._channels.default.builder("mast").readings) == 1
    assert loc.add_station("hill", fixed=True, position=(39.11, 117.21))
    assert not loc.add_station("bad", fixed=True, position=(95.0, 117.0))
    assert loc.view().rejected["fix_bad_position"] == 1
    loc.reset()
    loc.add_bearing(260.0, 45.0, 90.0, station="hill")
    assert len(loc._channels.default.builder("hill").readings) == 1


def test_stations_keep_their_own_tracks():
    """A fix of one station never places another's bearings."""
    loc = Localizer()
    loc.add_fix(0.0, 39.1, 117.2, station="a")
    loc.add_fix(1.0, 39.1, 117.2, station="a")
    loc.add_bearing(0.5, 10.0, 90.0, station="b")
    assert loc.view().rejected["before_first_fix"] == 1
    loc.add_fix(2.0, 39.1, 117.21, station="b")
    loc.add_fix(3.0, 39.1, 117.21, station="b")
    loc.add_bearing(2.5, 10.0, 90.0, station="b")
    (reading,) = loc._channels.default.builder("b").readings
    assert reading.east > 800  # at b's track, 0.01 deg of longitude east of a's


def test_a_walking_observer_whose_fix_comes_only_with_each_azimuth_minutes_apart_is_used():
    """The API as a surveyor feeds it: a fix and an azimuth at each stop, 10-40 min apart. The second fix confirms
    the first across the pause (a sparse stream), so no fix or bearing is refused and the emitter is located."""
    frame = LocalFrame(48.35, -53.98)
    loc = Localizer(LocalizerConfig(seed=1))
    stops = [(-400.0, 0.0), (0.0, -450.0), (380.0, 60.0), (50.0, 420.0)]
    stamp = 1.7e9
    for k, (e, n) in enumerate(stops):
        stamp += 600.0 * (1 + k)
        lat, lon, _ = frame.to_geodetic(e, n)
        loc.add_fix(stamp, lat, lon)
        loc.add_bearing(stamp, math.degrees(math.atan2(100.0 - e, 50.0 - n)) % 360.0, float("nan"))
    loc.flush()
    est = loc.finish() or loc.view().estimate
    loc.close()
    assert not loc.view().rejected, dict(loc.view().rejected)
    assert est is not None and est.bearings_used == 4
    lat, lon, _ = frame.to_geodetic(100.0, 50.0)
    assert math.hypot(*LocalFrame(lat, lon).to_enu(est.lat, est.lon)) < 60.0
