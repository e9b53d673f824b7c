"""A bag through the engine, offline: its fixes and bearings fed to a Localizer in log-time order, what it carried
(truth, datum, foreign messages, damage) kept, and the closing summary. Used by `replay --offline` and `report`."""
from __future__ import annotations

import math
import sys

from tqdm import tqdm

from aoa_localizer.engine.channels import DEFAULT
from aoa_localizer.engine.crlb import ellipse_axes
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.localizer import Localizer
from msgs_adapters.bag import BagError, read_bag


def summary(loc: Localizer, truths: dict[str, tuple], datum) -> list[str]:
    """Human-readable closing lines: the estimate (one line per channel when frequencies were heard), ellipse,
    counts, and each channel's error when the bag carries its truth (truth_of)."""
    lines = []
    view = loc.view()
    heard = [c for c in view.channels if c.estimate is not None]
    if not heard:
        lines.append(f"no estimate: {view.status}")
    for channel in heard:
        label = "" if channel.id == DEFAULT and len(heard) == 1 else (
            f"channel {channel.id}{' (retired)' if channel.retired else ''}: ")
        truth = truth_of(truths, channel.id, len(heard))
        lines += [label + line for line in _estimate_lines(view.frame, channel.estimate, truth, datum)]
    if "" in truths and len(heard) > 1 and not set(truths) & {c.id for c in heard}:
        lines.append(f"the bag's truth (/sim/truth) names no transmitter: not scored against the {len(heard)} "
                     "channels (a bag with several writes each one's on /sim/CHANNEL/truth)")
    rejected = ", ".join(f"{k} {v}" for k, v in sorted(view.rejected.items())) or "none"
    lines.append(f"inputs not used: {rejected}")
    return lines


def _estimate_lines(origin: LocalFrame, est, truth, datum) -> list[str]:
    a, b, _ = ellipse_axes(est.cov)
    # East/north in one frame only: the truth's (sim/datum) when the bag has it, else the engine's datum.
    if truth is not None and datum is not None:
        e, n = LocalFrame(*datum).to_enu(est.lat, est.lon)
        where = f"E {e:.1f} m, N {n:.1f} m from the bag's datum {datum[0]:.7f}, {datum[1]:.7f}"
    else:
        where = f"E {est.east:.1f} m, N {est.north:.1f} m from the datum {origin.lat0:.7f}, {origin.lon0:.7f}"
    lines = [f"estimate: lat {est.lat:.7f} lon {est.lon:.7f} ({where}), 95% ellipse semi-axes {a:.1f} x {b:.1f} m, "
             f"{est.bearings_used} bearings in {est.points_used} points"]
    if truth is not None and datum is not None:
        lines.append(f"error against the bag's truth (E {truth[1]:.1f} m, N {truth[2]:.1f} m, same frame): "
                     f"{math.hypot(e - truth[1], n - truth[2]):.2f} m")
    if est.transmitters:
        frame = LocalFrame(*datum) if truth is not None and datum is not None else origin
        places = [(frame.to_enu(t.lat, t.lon), t) for t in est.transmitters]
        lines.append(f"{est.transmitter_count} transmitters on this frequency (p = {est.count_probability:.2f}): "
                     + "; ".join(f"E {te:.1f} m, N {tn:.1f} m ({100 * t.share:.0f} %, {t.state})"
                                 for (te, tn), t in places))
        if truth is not None and datum is not None:
            nearest = min(math.hypot(te - truth[1], tn - truth[2]) for (te, tn), _ in places)
            lines.append(f"the transmitter nearest the bag's truth: {nearest:.2f} m from it")
    return lines


def truth_of(truths: dict[str, tuple], channel: str, channels: int) -> tuple | None:
    """The truth a channel is scored against: its own, or the bag's one /sim/truth when the run heard one channel
    (a truth that names no transmitter cannot be matched among several)."""
    if channel in truths:
        return truths[channel]
    return truths.get("") if channels == 1 else None


class BagRun:
    """What running a bag through the engine left: the truth and datum it carried, and the damage if any."""

    def __init__(self):
        # (stamp, east, north) in the scenario's map: each transmitter's by its channel, "" the bag's one /sim/truth
        self.truths: dict[str, tuple] = {}
        self.datum = None  # (lat, lon, alt) of that map
        self.damage: str | None = None
        self.messages = 0
        # "topic (type)": messages of a type the topic should not carry, or scans that hold no readings
        self.foreign: dict[str, int] = {}


def run_bag(bag, topics: dict, loc: Localizer, on_estimate, desc: str = "replay", stations=None) -> BagRun:
    """Feed a bag's fixes and bearings (of `stations`, {NAME: {kind: topic}}, when given) to `loc` in log-time
    order, call on_estimate(est) with each channel's newest estimate after each input (the final flush and
    check included: Localizer.run). Raises BagError when nothing could be read; damage later is recorded."""
    result = BagRun()

    def events():
        with tqdm(desc=desc, unit="msg", disable=None, file=sys.stderr) as bar:
            try:
                for event in read_bag(bag, topics, stations):
                    bar.update()
                    result.messages += 1
                    if event.kind == "truth":
                        result.truths[event.channel] = event.record
                    elif event.kind == "datum":
                        result.datum = (event.record.lat, event.record.lon, event.record.alt)
                    elif event.kind == "foreign":
                        key = "{} ({})".format(*event.record)
                        result.foreign[key] = result.foreign.get(key, 0) + 1
                    yield event
            except BagError as exc:
                if not result.messages:
                    raise
                result.damage = str(exc)

    for est in loc.run(events()):
        on_estimate(est)
    return result
