"""Several DF stations and several emitters, simulated: each station drives its own scenario track (or stands
still) and hears every emitter on its own carrier frequency at the same stamps (a receiver's VFOs share one).
Built on `simulate`, one run per (station, emitter); docs/benchmarks.md "Several stations and emitters"."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from aoa_localizer.simulation.scenarios import SCENARIOS, Scenario, simulate


@dataclass
class FleetData:
    """What the stations recorded: fixes (stamp, lat, lon, alt) and DF records (stamp, azimuth, quality,
    frequency Hz) per station, and each emitter's true ENU position by frequency (`truth`)."""

    fixes: dict[str, np.ndarray]
    bearings: dict[str, np.ndarray]
    truth: dict[float, np.ndarray]
    scenario: Scenario  # the first station's (datum, receiver settings)

    def events(self):
        """('fix' | 'bearing', station, row) of every station merged in stamp order."""
        tagged = [(f[0], 0, "fix", name, f) for name, rows in self.fixes.items() for f in rows]
        tagged += [(b[0], 1, "bearing", name, b) for name, rows in self.bearings.items() for b in rows]
        tagged.sort(key=lambda e: (e[0], e[1]))
        return [(kind, name, row) for _, _, kind, name, row in tagged]


def simulate_fleet(stations: dict[str, Scenario], emitters: dict[float, tuple[float, float]], seed: int) -> FleetData:
    """Every station's scenario (its track, noise, clocks) run against every emitter (frequency Hz -> ENU); the
    emitter field of the scenarios is ignored. Stations share the first one's datum."""
    fixes, bearings = {}, {}
    first = next(iter(stations.values()))
    for s_index, (name, sc) in enumerate(stations.items()):
        rows = []
        for e_index, (freq, where) in enumerate(emitters.items()):
            data = simulate(replace(sc, emitter=where, datum=first.datum), seed * 1000 + 37 * s_index + e_index)
            if e_index == 0:
                fixes[name] = data.fixes
            rows.append(np.column_stack([data.bearings, np.full(len(data.bearings), freq)]))
        merged = np.concatenate(rows)
        bearings[name] = merged[np.argsort(merged[:, 0], kind="stable")]
    return FleetData(fixes, bearings, {f: np.array(e, float) for f, e in emitters.items()}, first)


# Two vehicles on different roads around the `seed` scenario's emitter (E 1200, N 800): each alone sees it over a
# narrow span of directions; together their bearings cross at wide angles.
PAIR = {
    "car1": replace(SCENARIOS["seed"], name="car1", track=((0, 0), (1000, 0)), points=20),
    "car2": replace(SCENARIOS["seed"], name="car2", track=((2200, 1800), (2200, 800)), points=20),
}


@dataclass(frozen=True)
class Fleet:
    """A scenario with several stations: what the simulated vehicle plays (each station on NAME/gps/fix and
    NAME/df/bearing) and the node parameters that fuse them."""

    stations: dict[str, Scenario]
    emitters: dict[float, tuple[float, float]]

    @property
    def first(self) -> Scenario:
        return next(iter(self.stations.values()))

    def node_params(self) -> dict:
        return {"stations": list(self.stations)}


FLEETS = {"pair": Fleet(PAIR, {0.0: (1200.0, 800.0)})}
