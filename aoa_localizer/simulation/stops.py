"""A drive's readings taken with the vehicle stopped: the stop-and-go form of any simulated run.

Many DF crews stop to take their bearings (stop, read, drive on). `stopped` turns a run into that form: the
readings of each point are taken at one place (the point's mean true antenna place), with the same errors, and two
GPS fixes at that place bracket them; no fix in between stops. The moving run and its stopped form hold the same
information about the emitter, so an estimator should give both the same answer (issue: "Stopped = moving")."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from aoa_localizer.engine.geodesy import wrap_360
from aoa_localizer.simulation.scenarios import ScenarioData, _azimuths

POINT_S = 1.0  # a drive without the scenario's own points stops once per this many seconds of readings
_BRACKET_S = 0.05  # a stop's fixes this far before its first reading and after its last


def point_groups(data: ScenarioData) -> list[np.ndarray]:
    """The readings' indices by stop: the scenario's own points (stamps more than a second apart start a new one), or
    for a drive without points, every POINT_S of readings."""
    t = data.bearings[:, 0]
    if data.scenario.points:
        starts = np.flatnonzero(np.diff(t) > 1.0) + 1
    else:
        starts = np.flatnonzero(np.diff(np.floor((t - t[0]) / POINT_S)) > 0) + 1
    return np.split(np.arange(t.size), starts)


def stopped(data: ScenarioData, seed: int = 0) -> ScenarioData:
    """`data` with the vehicle stopped at each point: each point's readings from the point's mean true place (each
    reading's error kept: turned by the change of true azimuth), two fixes there around them (with the scenario's GPS
    noise, drawn from `seed`), no other fix. Needs azimuths from true north (no mount offset)."""
    sc = data.scenario
    if sc.mount_offset_deg is not None:
        raise ValueError("stopped() needs azimuths from true north")
    frame = data.frame
    rng = np.random.default_rng(seed)
    place = np.empty_like(data.sensor_enu)
    fixes = []
    for idx in point_groups(data):
        at = data.sensor_enu[idx].mean(axis=0)
        place[idx] = at
        for stamp in (data.bearings[idx[0], 0] - _BRACKET_S, data.bearings[idx[-1], 0] + _BRACKET_S):
            noisy = at + sc.gps_noise_m * rng.standard_normal(2)
            lat, lon, alt = frame.to_geodetic(noisy[0], noisy[1])
            fixes.append((stamp, float(lat), float(lon), float(alt)))
    bearings = data.bearings.copy()
    s_lat, s_lon, _ = frame.to_geodetic(data.sensor_enu[:, 0], data.sensor_enu[:, 1])
    p_lat, p_lon, _ = frame.to_geodetic(place[:, 0], place[:, 1])
    source = data.source if data.source is not None else np.zeros(len(bearings), int)
    places = data.transmitters_enu if data.transmitters_enu is not None else np.array([data.emitter_enu])
    targets = [(source == k, t) for k, t in enumerate(places)]
    if sc.moved_to is not None:  # a moved emitter: where it was before the move, where it is after
        late = bearings[:, 0] >= sc.moved_at_s
        targets = [(~late, np.array(sc.emitter, float)), (late, np.array(sc.moved_to, float))]
    for mine, target in targets:
        keep = mine & ~data.wild  # a wild reading points nowhere (a ghost at the reflector stays as drawn too)
        if np.any(keep):
            was = _azimuths(frame, data.sensor_enu[keep], s_lat[keep], s_lon[keep], np.asarray(target, float))
            now = _azimuths(frame, place[keep], p_lat[keep], p_lon[keep], np.asarray(target, float))
            bearings[keep, 1] = wrap_360(bearings[keep, 1] + now - was)
    return replace(data, fixes=np.array(fixes), bearings=bearings, sensor_enu=place)
