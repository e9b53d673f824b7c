"""The survey's maps (`locate --report`): an overview of every id, and a map per id zoomed to its own bearings, that
a person can read: each id's estimate numbered on the overview (the key beside the plot, never over it), and on its
own map its stations labelled, its bearing rays through the crossing, a bearing far off the estimate marked, the
95 % ellipse and the highest-density regions, a scale bar and the datum the metres are from."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from aoa_localizer.engine.crlb import ellipse_points
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.types import EstimateState

OFF_DEG = 30.0  # a bearing this far from the direction to the estimate is drawn as off (dashed, its angle named)
_MAX_RAYS = 300  # an id's map draws at most this many of its bearings (a sample of a long stream, faint)
_KEY_ROWS = 40  # the overview's key lists this many ids at most (more: numbers only, each id's own map names it)


def _printable(text: str) -> str:
    return "".join(ch if ch.isprintable() else "?" for ch in text) or "emitter"


def _scale_bar(ax) -> None:
    """A bar of a round length (1, 2 or 5 x 10^k m) about a fifth of the plot's width, bottom left."""
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    target = (x1 - x0) / 5.0
    power = 10.0 ** math.floor(math.log10(target))
    length = max((m * power for m in (1, 2, 5) if m * power <= target), default=power)
    x, y = x0 + 0.05 * (x1 - x0), y0 + 0.05 * (y1 - y0)
    ax.plot([x, x + length], [y, y], color="black", lw=3, solid_capstyle="butt")
    text = f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m" if length >= 1 else f"{length * 100:g} cm"
    ax.text(x + length / 2, y + 0.015 * (y1 - y0), text, ha="center", va="bottom", fontsize=9)


def _regions(ax, frame: LocalFrame, est, colour: str) -> None:
    for level, alpha in ((0.95, 0.12), (0.5, 0.25)):
        for ring in (est.regions or {}).get(level, []):
            e, n = frame.to_enu(ring[:, 0], ring[:, 1])
            ax.fill(e, n, color=colour, alpha=alpha, lw=0)


def overview(path: Path, frame: LocalFrame, found: dict) -> None:
    """Every id's estimate, numbered, with its 95 % ellipse, and the stations; the transmitters of an id that several
    share (k.j); the key of numbers beside the plot."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(13, 8))
    key = []
    stations: set[tuple[float, float]] = set()
    for k, (ident, (est, rows)) in enumerate(found.items(), start=1):
        ring = ellipse_points((est.east, est.north), est.cov)
        ax.plot(ring[:, 0], ring[:, 1], color="tab:blue", lw=0.8, alpha=0.5)
        ax.plot(est.east, est.north, "o", color="tab:red" if est.state != EstimateState.TRACKING else "tab:blue", ms=4)
        ax.annotate(str(k), (est.east, est.north), xytext=(3, 3), textcoords="offset points", fontsize=8)
        key.append(f"{k}  {_printable(ident)[:32]} ({est.state})"
                   + (f", {len(est.transmitters)} transmitters" if est.transmitters else ""))
        for j, t in enumerate(est.transmitters, start=1):
            ax.plot(*ellipse_points((t.east, t.north), t.cov).T, color="tab:green", lw=0.8, alpha=0.6)
            ax.plot(t.east, t.north, "x", color="tab:green", ms=5)
            ax.annotate(f"{k}.{j}", (t.east, t.north), xytext=(3, 3), textcoords="offset points", fontsize=7,
                        color="tab:green")
        stations.update((round(r.lat, 7), round(r.lon, 7)) for r in rows)
    if stations:
        e, n = frame.to_enu(np.array([s[0] for s in stations]), np.array([s[1] for s in stations]))
        ax.plot(e, n, "^", color="grey", ms=4, alpha=0.7, label="stations")
    ax.plot([], [], "o", color="tab:blue", ms=4, label="estimate (tracking)")
    ax.plot([], [], "o", color="tab:red", ms=4, label="estimate (other states)")
    ax.plot([], [], color="tab:blue", lw=0.8, label="95 % ellipse")
    if any(est.transmitters for est, _ in found.values()):
        ax.plot([], [], "x", color="tab:green", ms=5, label="transmitters of an id (k.j)")
    ax.set_aspect("equal")
    ax.set_xlabel(f"east (m) from {frame.lat0:.6f}, {frame.lon0:.6f}")
    ax.set_ylabel("north (m)")
    ax.set_title(f"{len(found)} emitters: estimates and 95 % ellipses (each id's own map in maps/)")
    _scale_bar(ax)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    text = "\n".join(key[:_KEY_ROWS] + ([f"... {len(key) - _KEY_ROWS} more"] if len(key) > _KEY_ROWS else []))
    ax.text(1.02, 0.78, text, transform=ax.transAxes, va="top", fontsize=7, family="monospace")
    fig.subplots_adjust(left=0.07, right=0.66, top=0.94, bottom=0.08)  # the key's column right of the plot
    fig.savefig(path, dpi=110)
    plt.close(fig)


def id_map(path: Path, frame: LocalFrame, ident: str, est, rows) -> None:
    """One id zoomed to its own stations and estimate: stations labelled, each bearing a ray through and past the
    crossing (dashed and its angle named when more than OFF_DEG off the estimate), the estimate, its 95 % ellipse,
    its 50 % and 95 % highest-density regions, and each transmitter when several share the id."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 7))
    ring = ellipse_points((est.east, est.north), est.cov)
    _regions(ax, frame, est, "tab:orange")
    places, view = [], [ring]
    labelled: set[tuple[float, float]] = set()
    for row in rows[:: math.ceil(len(rows) / _MAX_RAYS)]:  # a stream of readings: a sample of its rays
        e, n = frame.to_enu(row.lat, row.lon)
        places.append((e, n))
        to_est = math.degrees(math.atan2(est.east - e, est.north - n)) % 360.0
        off = (row.azimuth_deg - to_est + 180.0) % 360.0 - 180.0
        reach = 1.3 * math.hypot(est.east - e, est.north - n) + float(np.max(np.hypot(*(ring - ring.mean(0)).T)))
        th = math.radians(90.0 - row.azimuth_deg)
        far = abs(off) > OFF_DEG
        ax.plot([e, e + reach * math.cos(th)], [n, n + reach * math.sin(th)], color="tab:red" if far else "tab:blue",
                lw=1.0, ls="--" if far else "-", alpha=0.8 if len(rows) <= _MAX_RAYS else 0.2)
        if (round(e, 1), round(n, 1)) in labelled:  # each station named once
            continue
        labelled.add((round(e, 1), round(n, 1)))
        label = row.station or f"row {row.line}"
        ax.annotate(_printable(label) + (f" ({off:+.0f} deg off)" if far and len(rows) <= _MAX_RAYS else ""), (e, n),
                    xytext=(4, -10), textcoords="offset points", fontsize=8, color="tab:red" if far else "black")
    for k, t in enumerate(est.transmitters, start=1):
        ring_k = ellipse_points((t.east, t.north), t.cov)
        ax.plot(ring_k[:, 0], ring_k[:, 1], color="tab:green", lw=1.2, label="transmitters (95 %)" if k == 1 else None)
        ax.plot(t.east, t.north, "x", color="tab:green", ms=9, mew=2)
        ax.annotate(f"transmitter {k} ({100 * t.share:.0f} %)", (t.east, t.north), xytext=(5, 5),
                    textcoords="offset points", fontsize=8, color="tab:green")
        view.append(ring_k)  # the view holds every transmitter too
    pe, pn = np.array(places).T if places else (np.array([]), np.array([]))
    ax.plot(pe, pn, "^", color="black", ms=7, label="stations")
    ax.plot([], [], color="tab:blue", label="bearings")
    ax.plot([], [], color="tab:red", ls="--", label=f"bearings over {OFF_DEG:g} deg off the estimate")
    ax.plot(ring[:, 0], ring[:, 1], color="tab:orange", lw=1.5, label="95 % ellipse")
    ax.fill([], [], color="tab:orange", alpha=0.25, label="50 % / 95 % regions")
    ax.plot(est.east, est.north, "+", color="black", ms=14, mew=2, label="estimate")
    xs = np.concatenate([pe, *(v[:, 0] for v in view), [est.east]])
    ys = np.concatenate([pn, *(v[:, 1] for v in view), [est.north]])
    span = max(float(np.ptp(xs)), float(np.ptp(ys)), 1e-6)
    ax.set_xlim(xs.min() - 0.15 * span, xs.max() + 0.15 * span)
    ax.set_ylim(ys.min() - 0.15 * span, ys.max() + 0.15 * span)
    ax.set_aspect("equal", adjustable="box")  # the limits hold the view; the box takes the shape
    ax.set_xlabel(f"east (m) from {frame.lat0:.6f}, {frame.lon0:.6f}")
    ax.set_ylabel("north (m)")
    ax.set_title(f"{_printable(ident)}: {est.lat:.6f}, {est.lon:.6f} ({est.state}), "
                 f"{len(rows)} bearings", fontsize=10)
    _scale_bar(ax)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    fig.subplots_adjust(left=0.1, right=0.68, top=0.93, bottom=0.09)  # fixed: tight_layout cost a third of a map
    fig.savefig(path, dpi=110)
    plt.close(fig)
