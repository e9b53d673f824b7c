"""Pictures a monitoring engineer reads: the map of a localisation, its error against the bound, and the
benchmarks' RMSE curves. matplotlib with the Agg backend (headless)."""
from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar  # noqa: E402

from aoa_localizer.engine.crlb import ellipse_axes, ellipse_points  # noqa: E402
from aoa_localizer.reporting.export import moving_by_channel  # noqa: E402
from msgs_adapters.build import channel_colour  # noqa: E402

PATH_ELLIPSES = 8  # a moving transmitter's path on the map carries this many of its 95 % ellipses

RAYS_MAX = 400  # used rays drawn (evenly thinned beyond that); every gated-out one is drawn
CLIP_FACTOR = 1000.0  # rmse_curves: a series above this many times the reference is clipped


# The stations' track styles.
TRACK_STYLES = ("-", "--", ":", "-.")


def nice_length(span: float) -> float:
    """A 1-2-5 length near a fifth of span, for the scale bar."""
    target = max(span / 5.0, 1e-9)
    exp = math.floor(math.log10(target))
    return min((m * 10**exp for m in (1, 2, 5, 10)), key=lambda v: abs(v - target))


def _rays(readings: np.ndarray, target, keep_all: bool, t_range, colour) -> LineCollection:
    """Segments from each antenna along its bearing, 1.2 x the distance to the target, fading with age."""
    t0, t1 = t_range
    seg, rgba = [], []
    for stamp, e, n, theta, _sigma in readings:
        length = 1.2 * math.hypot(target[0] - e, target[1] - n) + 20.0
        seg.append([(e, n), (e + length * math.cos(theta), n + length * math.sin(theta))])
        age = (stamp - t0) / (t1 - t0) if t1 > t0 else 1.0
        rgba.append((*colour, 0.08 + (0.25 if keep_all else 0.45) * age))
    return LineCollection(seg, colors=rgba, linewidths=0.6 if not keep_all else 0.9,
                          linestyles="dashed" if keep_all else "solid")


def map_figure(path, frame, tracks: dict[str, np.ndarray], readings: np.ndarray, kept: np.ndarray, est,
               truth=None, title_extra: str = "", others=(), posterior=None, history=()):
    """map.png: each station's track (rows stamp, east, north), bearing rays (used: blue, fading with age; gated
    out as wild: red dashed), particles, estimate with its 95 % ellipse, the posterior's 95 % region (`posterior`,
    a PosteriorGrid, as emitter/posterior shows it), the other emitters' (channels') estimates and ellipses in
    their colours, a moving transmitter's path (through the `moving` estimates of `history`, the run's estimates)
    with its ellipses over time, truth if known; metres at the datum, scale bar. The zoom on the estimate and the
    legend sit in their own panels beside the map, so neither hides any of the track."""
    fig = plt.figure(figsize=(12, 8), dpi=110)
    grid = fig.add_gridspec(2, 2, width_ratios=(3, 1.15), height_ratios=(1, 1.1))
    ax = fig.add_subplot(grid[:, 0])
    target = (est.east, est.north)
    _draw_inputs(ax, tracks, readings, kept, target)
    if posterior is not None:
        _draw_posterior(ax, posterior)
    for other in others:
        colour = channel_colour(other.channel) or (0.5, 0.5, 0.5)  # as in RViz; the default channel grey
        ring_o = ellipse_points((other.east, other.north), other.cov)
        ax.plot(ring_o[:, 0], ring_o[:, 1], color=colour, lw=1.2, zorder=4)
        ax.plot(other.east, other.north, "x", color=colour, ms=9, mew=2, zorder=5, label=f"emitter {other.channel}")
    path_points = draw_paths(ax, history)
    ring = ellipse_points(target, est.cov)
    if est.particles is not None:
        ax.scatter(est.particles[:, 0], est.particles[:, 1], s=4, color="0.45", alpha=0.6, label="particles", zorder=3)
    ax.plot(ring[:, 0], ring[:, 1], color="orange", lw=1.5, label="95 % ellipse", zorder=4)
    ax.plot(*target, "x", color="red", ms=10, mew=2, label="estimate", zorder=5)
    for i, (e, n, mass) in enumerate(getattr(est, "modes", None) or []):
        if len(est.modes) > 1:
            ax.plot(e, n, "D", color="purple", ms=7, mfc="none", mew=1.5, zorder=5,
                    label="posterior modes (probability)" if i == 0 else None)
            ax.annotate(f"{100 * mass:.0f} %", (e, n), textcoords="offset points", xytext=(6, 6), color="purple")
    if truth is not None:
        ax.plot(*truth, "*", color="green", ms=14, label="truth", zorder=6)
    ax.plot([], [], color=(0.12, 0.35, 0.85), lw=1, label="bearings used (older: fainter)")
    if not kept.all():
        ax.plot([], [], color=(0.85, 0.1, 0.1), lw=1, ls="--", label="bearings gated out as wild")
    pts = [rows[:, 1:3] for rows in tracks.values() if len(rows)]
    pts.append(np.array([target] + [(o.east, o.north) for o in others]))
    pts.extend(path_points)
    if truth is not None:
        pts.append(np.array([truth]))
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.08 * max(hi - lo) + 50.0
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    span = ax.get_xlim()[1] - ax.get_xlim()[0]
    bar = nice_length(span)
    ax.add_artist(
        AnchoredSizeBar(ax.transData, bar, f"{bar:g} m", "lower left", pad=0.6, frameon=False, size_vertical=0)
    )
    a, b, _ = ellipse_axes(est.cov)
    ax.set_title(
        f"Emitter at {est.lat:.6f}, {est.lon:.6f} ({est.algorithm}; 95 % ellipse {a:.1f} x {b:.1f} m)\n"
        f"map frame: ENU metres at datum {frame.lat0:.6f}, {frame.lon0:.6f}{title_extra}",
        fontsize=10,
    )
    _zoom(fig.add_subplot(grid[0, 1]), est, ring, truth, a, posterior)
    legend_panel = fig.add_subplot(grid[1, 1])
    legend_panel.axis("off")
    legend_panel.legend(*ax.get_legend_handles_labels(), loc="upper left", fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_paths(ax, estimates, ellipses: int = PATH_ELLIPSES) -> list[np.ndarray]:
    """Each channel's path as a moving transmitter (export.moving_by_channel): a line through its `moving`
    estimates' places in time order and the 95 % ellipses of `ellipses` of them spread evenly over the path (the
    first and the last among them); returns the places drawn, one array per channel."""
    drawn = []
    for n, (channel, ests) in enumerate(moving_by_channel(estimates).items()):
        colour = channel_colour(channel) or (0.8, 0.35, 0.0)  # the default channel in dark orange
        places = np.array([(e.east, e.north) for e in ests])
        ax.plot(places[:, 0], places[:, 1], "-", color=colour, lw=1.6, zorder=4,
                label="moving transmitter: path, 95 % ellipses over time" if n == 0 else None)
        for k in np.unique(np.linspace(0, len(ests) - 1, min(ellipses, len(ests))).round().astype(int)):
            ring = ellipse_points(places[k], ests[k].cov)
            ax.plot(ring[:, 0], ring[:, 1], color=colour, lw=0.8, alpha=0.7, zorder=4)
        drawn.append(places)
    return drawn


def _draw_inputs(ax, tracks: dict[str, np.ndarray], readings: np.ndarray, kept: np.ndarray, target):
    """The stations' tracks and the bearing rays (at most RAYS_MAX of the used ones; the wild ones dashed)."""
    t_range = (readings[:, 0].min(), readings[:, 0].max()) if len(readings) else (0.0, 1.0)
    used, wild = readings[kept], readings[~kept]
    if len(used) > RAYS_MAX:
        used = used[np.linspace(0, len(used) - 1, RAYS_MAX).astype(int)]
    if len(used):
        ax.add_collection(_rays(used, target, False, t_range, (0.12, 0.35, 0.85)))
    if len(wild):
        ax.add_collection(_rays(wild, target, True, t_range, (0.85, 0.1, 0.1)))
    for k, (station, fixes) in enumerate(tracks.items()):
        if len(fixes):
            style = TRACK_STYLES[k % len(TRACK_STYLES)]
            ax.plot(fixes[:, 1], fixes[:, 2], color="0.25", lw=1.6, ls=style,
                    label=f"vehicle track {station}" if station else "vehicle track")
            ax.plot(fixes[0, 1], fixes[0, 2], "o", color="0.25", ms=5)


def _draw_posterior(ax, grid, origin=(0.0, 0.0)):
    """The posterior grid's 95 % region (its cells valued 5-100, darker: more probable), `origin` taken off."""
    n = grid.value.shape[0]
    left, bottom = grid.east0 - origin[0], grid.north0 - origin[1]
    shown = np.ma.masked_equal(grid.value.astype(float), 0.0)
    ax.imshow(shown, origin="lower", cmap="Purples", vmin=0, vmax=100, alpha=0.55, interpolation="nearest",
              extent=(left, left + n * grid.resolution, bottom, bottom + n * grid.resolution), zorder=2)
    ax.plot([], [], "s", color=(0.6, 0.5, 0.8), ms=8, label="posterior, 95 % region (emitter/posterior)")


def _zoom(ins, est, ring: np.ndarray, truth, a: float, posterior=None):
    """A zoom on the estimate: the ellipse is metres wide on a map kilometres wide."""
    target = (est.east, est.north)
    if posterior is not None:
        _draw_posterior(ins, posterior, target)
        ins.set_autoscale_on(False)
    half = max(4 * a, 10.0)
    if truth is not None:
        half = max(half, 1.3 * math.hypot(truth[0] - target[0], truth[1] - target[1]))
    rel = lambda xy: (np.asarray(xy)[..., 0] - target[0], np.asarray(xy)[..., 1] - target[1])  # noqa: E731
    if est.particles is not None:
        ins.scatter(*rel(est.particles), s=5, color="0.45", alpha=0.6)
    ins.plot(*rel(ring), color="orange", lw=1.5)
    ins.plot(0.0, 0.0, "x", color="red", ms=9, mew=2)
    if truth is not None:
        ins.plot(*rel(np.array(truth)), "*", color="green", ms=12)
    ins.set_xlim(-half, half)
    ins.set_ylim(-half, half)
    ins.set_aspect("equal")
    ins.locator_params(nbins=5)
    ins.tick_params(labelsize=7)
    ins.set_title("zoom: metres from the estimate", fontsize=9)


def error_figure(path, t, error, bound, major):
    """error.png: error against time with the CRLB of the bearings used so far and the ellipse's semi-major axis."""
    fig, ax = plt.subplots(figsize=(9, 4.5), dpi=110)
    t = np.asarray(t) - t[0]
    ax.semilogy(t, error, color="red", lw=1.5, label="error of the estimate")
    ax.semilogy(t, bound, color="black", lw=1.2, ls="--", label="CRLB of the bearings used so far (RMSE bound)")
    ax.semilogy(t, major, color="orange", lw=1.2, label="95 % ellipse, semi-major axis")
    ax.set_xlabel("time since the first estimate (s)")
    ax.set_ylabel("metres")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Is the filter as good as the bearings allow? (error near the bound, inside the ellipse)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def rmse_curves(path, title: str, curves: dict, bound=None, xlabel="observation point", ylabel="RMSE (m)",
                log=True) -> dict:
    """RMSE against step, one line per filter, and the bound if given: the benchmarks' --plot. Every series has
    its own colour and dash (tab20 by four dashes); a diverged series is clipped at CLIP_FACTOR x the bound (or
    the median series) and marked, so it cannot squash the others. Returns each label's (colour, dash) and the
    clip level, for the tests."""
    fig, ax = plt.subplots(figsize=(9, 5), dpi=100)
    colours, dashes = [plt.get_cmap("tab20")(k) for k in range(20)], ("-", "--", "-.", ":")
    finite = [np.asarray(y, float)[np.isfinite(y)] for _, y in curves.values()]
    reference = np.max(bound[1]) if bound is not None else np.median([np.median(y) for y in finite if len(y)])
    top = CLIP_FACTOR * float(reference)
    drawn = {}
    for i, (name, (x, y)) in enumerate(curves.items()):
        x, y = np.asarray(x, float), np.asarray(y, float)
        over = ~np.isfinite(y) | (y > top)
        label = name if not over.any() else f"{name} (diverged: clipped at {top:.3g})"
        style = (colours[i % len(colours)], dashes[(i // 2) % len(dashes)])
        ax.plot(x, np.where(over, top, y), color=style[0], ls=style[1], lw=1.3, label=label)
        if over.any():
            ax.plot(x[over], np.full(over.sum(), top), "^", color=style[0], ms=4)
        drawn[label] = style
    if bound is not None:
        ax.plot(bound[0], bound[1], color="black", ls="--", lw=1.2, label="CRLB")
    if log:
        ax.set_yscale("log")
    ax.set_ylim(top=1.5 * top)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return {"styles": drawn, "clip": top}
