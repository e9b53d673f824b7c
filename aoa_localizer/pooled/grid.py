"""One emitter's position posterior on a grid that follows its stations: geometry, likelihood and zooming.

The grid starts at the stations' centroid, 12 prior scales wide, and zooms onto the box that holds the posterior's
mass until it stops shrinking; the mass each zoom leaves outside is kept in the evidence, so a wide noise
hypothesis is not favoured or punished by where the grid happens to end. The position prior is a bivariate
Cauchy at the centroid whose scale is the larger of the stations' spread and the median distance to the bearings'
crossings: it only keeps the mass of near-parallel rays finite, and scales with the layout.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aoa_localizer.engine.geodesy import LocalFrame, wrap_pi
from aoa_localizer.engine.inference.triangulation import least_squares_crossing
from aoa_localizer.engine.scheduling.slices import SURVEY_GRID, metered
from aoa_localizer.pooled.noise_family import NoiseGrid, log_likelihood, logsumexp

CELLS = 48  # cells a side
_ELEMENTS_AT_ONCE = 20_000  # stations x scales x cells a log likelihood makes at once: well under a millisecond
_FIRST_HALF_WIDTH = 12.0  # prior scales: the Cauchy prior holds 92 % within
_KEEP = 0.9995  # the mass a zoomed box keeps
_MAX_ZOOMS = 5


@dataclass(frozen=True)
class Geometry:
    """One emitter's stations in a frame at their centroid: places (K, 2) m, centres (K,) rad from north, their own
    variance (K,) rad^2, receivers (K,), and the prior's scale (m)."""

    emitter: str
    frame: LocalFrame
    xy: np.ndarray
    centre: np.ndarray
    var: np.ndarray
    receivers: tuple
    names: tuple
    prior_scale: float


@dataclass(frozen=True)
class Box:
    """A grid's centre and half-widths (m)."""

    cx: float
    cy: float
    hx: float
    hy: float

    def cells(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Cell centres x (G,), y (G,) and a cell's area (m^2)."""
        dx, dy = 2 * self.hx / CELLS, 2 * self.hy / CELLS
        x = self.cx - self.hx + dx * (np.arange(CELLS) + 0.5)
        y = self.cy - self.hy + dy * (np.arange(CELLS) + 0.5)
        return x, y, dx * dy


def crossing_scale(xy: np.ndarray, centre: np.ndarray) -> float:
    """Median distance from the centroid to the crossings of pairs of bearings ahead of both stations (0: none)."""
    u = np.column_stack([np.sin(centre), np.cos(centre)])  # each bearing's direction (east, north)
    dists = []
    for i in range(len(xy)):
        for j in range(i + 1, len(xy)):
            a = np.column_stack([u[i], -u[j]])
            if abs(np.linalg.det(a)) < 1e-9:
                continue
            t = np.linalg.solve(a, xy[j] - xy[i])
            if t[0] > 0 and t[1] > 0:
                dists.append(float(np.hypot(*(xy[i] + t[0] * u[i]))))
    return float(np.median(dists)) if dists else 0.0


def prior_scale(xy: np.ndarray, centre: np.ndarray) -> float:
    """The position prior's scale (m): the larger of the stations' RMS spread and the crossings' distance."""
    spread = float(np.sqrt(np.mean(np.sum(xy**2, axis=1))))
    return max(spread, crossing_scale(xy, centre))


def first_box(geom: Geometry) -> Box:
    h = _FIRST_HALF_WIDTH * geom.prior_scale
    return Box(0.0, 0.0, h, h)


def log_prior_at(x: np.ndarray, y: np.ndarray, scale: float) -> np.ndarray:
    """log of a bivariate Cauchy at the origin with this scale, at places (x[i], y[i])."""
    return -math.log(2 * math.pi * scale**2) - 1.5 * np.log1p((x**2 + y**2) / scale**2)


def log_prior(x: np.ndarray, y: np.ndarray, scale: float) -> np.ndarray:
    """log_prior_at on the grid (G*G,) (rows y, columns x)."""
    gx, gy = np.meshgrid(x, y)
    return log_prior_at(gx.ravel(), gy.ravel(), scale)


def log_joint(geom: Geometry, box: Box, shift: np.ndarray, extra_var: np.ndarray, noise: NoiseGrid) -> np.ndarray:
    """log p(bearings, position in cell | hypothesis) + log cell area: (H, G*G), rows y, columns x.

    `shift` (K,) rad is subtracted from each station's centre (its receiver's learned bias); `extra_var` (K,)
    rad^2 is that bias's own uncertainty."""
    x, y, area = box.cells()
    gx, gy = np.meshgrid(x, y)
    gx, gy = gx.ravel(), gy.ravel()
    ex, ey = gx[None, :] - geom.xy[:, :1], gy[None, :] - geom.xy[:, 1:]
    pred = np.arctan2(ex, ey)  # (K, C)
    resid = wrap_pi(geom.centre[:, None] - shift[:, None] - pred)
    prior = log_prior(x, y, geom.prior_scale) + math.log(area)
    # A cell is a place spread over its area, not its centre: the bearing to it spreads by the cell's width across
    # the bearing over the range (uniform: a twelfth of its square), so a ridge thinner than a cell (precise
    # bearings) keeps its mass wherever the cells' centres fall
    dx, dy = 2 * box.hx / CELLS, 2 * box.hy / CELLS
    across = ((dx * ey) ** 2 + (dy * ex) ** 2) / np.maximum(ex**2 + ey**2, 1e-300)
    var = (geom.var + extra_var)[:, None] + across / (12.0 * np.maximum(ex**2 + ey**2, 1e-300))
    return _log_likelihood_in_parts(resid, var, noise) + prior[None, :]


@metered(SURVEY_GRID, lambda resid, var, noise: resid.size * noise.scales[0].size)
def _cells_log_likelihood(resid: np.ndarray, var: np.ndarray, noise: NoiseGrid) -> np.ndarray:
    """log_likelihood over some of a grid's cells (each cell's own: a grid's cells are made a part at a time)."""
    return log_likelihood(resid, var, noise)


def _log_likelihood_in_parts(resid: np.ndarray, var: np.ndarray, noise: NoiseGrid) -> np.ndarray:
    """log_likelihood over places (K, C), _ELEMENTS_AT_ONCE densities at a time (each part metered)."""
    step = max(1, _ELEMENTS_AT_ONCE // (resid.shape[0] * noise.scales[0].size))
    return np.concatenate([_cells_log_likelihood(resid[:, lo:lo + step], var[:, lo:lo + step], noise)
                           for lo in range(0, resid.shape[1], step)], axis=1)


def mixture(lj: np.ndarray, log_z: np.ndarray, log_w: np.ndarray) -> np.ndarray:
    """The position posterior over the cells (C,), normalised: sum_h w_h p(cell | bearings, h)."""
    log_p = logsumexp(lj - log_z[:, None] + log_w[:, None], axis=0)
    p = np.exp(log_p - log_p.max())
    return p / p.sum()


def log_density(geom: Geometry, shift: np.ndarray, extra_var: np.ndarray, noise: NoiseGrid, log_w: np.ndarray,
                log_z: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The mixture posterior's log density (up to the same constant everywhere) at places (x[i], y[i]): what
    `mixture` gives a grid's cells, at any place."""
    pred = np.arctan2(x[None, :] - geom.xy[:, :1], y[None, :] - geom.xy[:, 1:])
    resid = wrap_pi(geom.centre[:, None] - shift[:, None] - pred)
    var = np.broadcast_to((geom.var + extra_var)[:, None], resid.shape)
    lj = _log_likelihood_in_parts(resid, var, noise) + log_prior_at(x, y, geom.prior_scale)[None, :]
    return logsumexp(lj - log_z[:, None] + log_w[:, None], axis=0)


_REFINE_SIDE = 15  # a refining grid's points a side ...
_REFINE_LEVELS = 6  # ... each level spanning two of the last level's spacings each way (a cell / 1900 at the end)


def refined_mode(geom: Geometry, box: Box, p: np.ndarray, shift: np.ndarray, extra_var: np.ndarray,
                 noise: NoiseGrid, log_w: np.ndarray, log_z: np.ndarray) -> np.ndarray:
    """The posterior's mode past the grid's cells: from the three heaviest cells and the bearings' least-squares
    crossing, finer grids around the best place so far, each spanning two spacings of the last. A peak far
    narrower than a cell (precise bearings under a wide wild-share component) is found where the cells' centres
    only brush it."""
    x, y, _ = box.cells()
    step = np.array([x[1] - x[0], y[1] - y[0]])
    rows, cols = np.divmod(np.argsort(p)[::-1][:3], CELLS)
    starts = [np.array([x[c], y[r]]) for r, c in zip(rows, cols, strict=True)]
    cross = least_squares_crossing(geom.xy, np.pi / 2 - (geom.centre - shift))
    if cross is not None and np.all(np.abs(cross - [box.cx, box.cy]) <= [box.hx, box.hy]):
        starts.append(cross)
    offsets = np.linspace(-2.0, 2.0, _REFINE_SIDE)
    gx, gy = (g.ravel() for g in np.meshgrid(offsets, offsets))
    best, best_value = starts[0], -np.inf
    for _ in range(_REFINE_LEVELS):
        cx = np.concatenate([s[0] + gx * step[0] for s in starts])
        cy = np.concatenate([s[1] + gy * step[1] for s in starts])
        value = log_density(geom, shift, extra_var, noise, log_w, log_z, cx, cy)
        i = int(np.argmax(value))
        if value[i] > best_value:
            best, best_value = np.array([cx[i], cy[i]]), float(value[i])
        starts, step = [best], step * 4.0 / (_REFINE_SIDE - 1)
    return best


def heaviest(p: np.ndarray) -> np.ndarray:
    """The indices of the fewest cells holding _KEEP of the mass `p`."""
    order = np.argsort(p)[::-1]
    return order[: int(np.searchsorted(np.cumsum(p[order]), _KEEP)) + 1]


def mass_box(box: Box, p: np.ndarray) -> Box:
    """The smallest grid-aligned box holding _KEEP of the cells' mass, two cells wider each side."""
    rows, cols = np.divmod(heaviest(p), CELLS)
    x, y, _ = box.cells()
    dx, dy = 2 * box.hx / CELLS, 2 * box.hy / CELLS
    x0, x1 = x[cols.min()] - 2.5 * dx, x[cols.max()] + 2.5 * dx
    y0, y1 = y[rows.min()] - 2.5 * dy, y[rows.max()] + 2.5 * dy
    hx, hy = (x1 - x0) / 2, (y1 - y0) / 2
    # a box thinner than 1:4 resolves its long side too coarsely for a curved (banana) posterior
    hx, hy = max(hx, hy / 4), max(hy, hx / 4)
    return Box((x0 + x1) / 2, (y0 + y1) / 2, hx, hy)


def outside(box: Box, inner: Box) -> np.ndarray:
    """Mask (G*G,) of `box`'s cells whose centres lie outside `inner`."""
    x, y, _ = box.cells()
    gx, gy = np.meshgrid(x, y)
    return ((np.abs(gx - inner.cx) > inner.hx) | (np.abs(gy - inner.cy) > inner.hy)).ravel()


@dataclass(frozen=True)
class Zoomed:
    """The last grid of a zoom, its log joint (H, C), and each hypothesis's evidence (H,) over every grid."""

    box: Box
    log_joint: np.ndarray
    log_z: np.ndarray


def zoom(geom: Geometry, shift: np.ndarray, extra_var: np.ndarray, noise: NoiseGrid,
         log_w: np.ndarray | None, start: Box | None = None) -> Zoomed:
    """Grids from `start` (12 prior scales) down to the box holding the posterior's mass (under hypothesis weights
    `log_w`; None: the emitter's own posterior over the hypotheses)."""
    box = start or first_box(geom)
    lj = log_joint(geom, box, shift, extra_var, noise)
    left = np.full(noise.size, -np.inf)  # evidence left outside the zoomed boxes
    for _ in range(_MAX_ZOOMS):
        log_z = np.logaddexp(logsumexp(lj, axis=1), left)
        weights = noise.log_prior + log_z if log_w is None else log_w
        inner = mass_box(box, mixture(lj, log_z, weights - logsumexp(weights, axis=0)))
        if inner.hx > 0.5 * box.hx and inner.hy > 0.5 * box.hy:
            break
        mask = outside(box, inner)
        left = np.logaddexp(left, logsumexp(np.where(mask[None, :], lj, -np.inf), axis=1))
        box = inner
        lj = log_joint(geom, box, shift, extra_var, noise)
    return Zoomed(box, lj, np.logaddexp(logsumexp(lj, axis=1), left))


def evidence(geom: Geometry, shift: np.ndarray, extra_var: np.ndarray, noise: NoiseGrid) -> tuple[np.ndarray, Box]:
    """Each hypothesis's log evidence (H,), each band of scales zoomed onto its own posterior (on a grid sized for
    the wide hypotheses a sharp one's peak falls between cells), and the smallest box holding every band's."""
    out = np.empty(noise.size)
    boxes = []
    for band in noise.bands():
        z = zoom(geom, shift, extra_var, noise.subset(band), None)
        out[band] = z.log_z
        boxes.append(z.box)
    x0, x1 = min(b.cx - b.hx for b in boxes), max(b.cx + b.hx for b in boxes)
    y0, y1 = min(b.cy - b.hy for b in boxes), max(b.cy + b.hy for b in boxes)
    return out, Box((x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2, (y1 - y0) / 2)


def widened(box: Box, margin: float) -> Box:
    """The box with `margin` metres more on every side."""
    return Box(box.cx, box.cy, box.hx + margin, box.hy + margin)


def median_range(xy: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The median distance from each place (x[i], y[i]) to the stations `xy` (K, 2)."""
    return np.median(np.hypot(x[None, :] - xy[:, :1], y[None, :] - xy[:, 1:]), axis=0)


def rebinned(src: Box, p: np.ndarray, out: Box) -> np.ndarray:
    """The mass of cells `p` on `src` moved to the cells of the wider box `out` that hold their centres."""
    x, y, _ = src.cells()
    gx, gy = np.meshgrid(x, y)
    ox, oy, _ = out.cells()
    half_x, half_y = out.hx / CELLS, out.hy / CELLS
    edges_x = np.concatenate([ox - half_x, [ox[-1] + half_x]])
    edges_y = np.concatenate([oy - half_y, [oy[-1] + half_y]])
    mass, _, _ = np.histogram2d(gy.ravel(), gx.ravel(), bins=(edges_y, edges_x), weights=p)
    return mass.ravel()


def displaced(src: Box, p: np.ndarray, out: Box, xy: np.ndarray, shares: np.ndarray, weights: np.ndarray,
              cap_m: float, scale: float, floor_m: float) -> np.ndarray:
    """The truth's posterior on `out` (C,) when the bearings point at an apparent place (posterior `p` on `src`)
    displaced from the truth by an isotropic Gaussian whose sigma is one of `shares` (prior `weights`) of the
    truth's own median range to the stations `xy` (at most `cap_m`, at least `floor_m`): a truth farther out than
    the crossing is displaced further, so the posterior leans outward. The apparent place's Cauchy prior (`scale`)
    is divided out and the truth's applied."""
    sx, sy, _ = src.cells()
    ax, ay = (g.ravel() for g in np.meshgrid(sx, sy))
    keep = heaviest(p)
    ax, ay = ax[keep], ay[keep]
    like = p[keep] / np.exp(log_prior_at(ax, ay, scale))
    ox, oy, _ = out.cells()
    gx, gy = (g.ravel() for g in np.meshgrid(ox, oy))
    reach = np.minimum(median_range(xy, gx, gy), cap_m)
    # single precision for the (cells x places) kernel: a smoothing, read to a few digits
    d2 = (np.subtract.outer(gx, ax, dtype=np.float32) ** 2 + np.subtract.outer(gy, ay, dtype=np.float32) ** 2)
    prior = np.exp(log_prior_at(gx, gy, scale))
    q = np.zeros(gx.size)
    for share, weight in zip(shares, weights, strict=True):
        var = (np.maximum(share * reach, floor_m) ** 2).astype(np.float32)[:, None]
        one = ((np.exp(d2 / (-2.0 * var)) / var) @ like.astype(np.float32)).astype(float) * prior
        q += weight * one / one.sum()  # each share's posterior, normalised, mixed by the shares' prior weights
    return q / q.sum()
