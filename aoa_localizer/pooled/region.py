"""What a grid posterior says: its point, its moments, its highest-density regions and what an ellipse holds.

The point is the posterior's mode (its most probable place, refined within its cell), which a heavy-tailed or
banana-shaped posterior does not drag along its tails as it drags the mean (docs/design.md compares it with the
spatial median); the covariance is the moment about it. The 50 % and
95 % highest-density regions are polygons (they hold the mass whatever the shape), and the mass inside the
covariance's own 50 % and 95 % ellipses says when those ellipses understate or overstate the posterior.
"""
from __future__ import annotations

from dataclasses import dataclass

import contourpy
import numpy as np

from aoa_localizer.engine.crlb import ELLIPSE_50, ELLIPSE_95
from aoa_localizer.pooled.grid import CELLS, Box

LEVELS = (0.5, 0.95)


@dataclass(frozen=True)
class Region:
    """A posterior's summary in its grid's frame (m)."""

    point: np.ndarray  # (2,)
    cov: np.ndarray  # (2, 2) about the point
    hpd: dict  # level -> list of closed rings (M, 2)
    ellipse_mass: dict  # level -> the posterior mass inside the covariance's ellipse of that level


def mode(box: Box, p: np.ndarray) -> np.ndarray:
    """The most probable cell's centre, moved to the vertex of a parabola through its log density and its
    neighbours' along each axis (at most half a cell)."""
    grid = p.reshape(CELLS, CELLS)
    r, c = np.unravel_index(int(np.argmax(grid)), grid.shape)
    x, y, _ = box.cells()
    out = np.array([x[c], y[r]])
    with np.errstate(divide="ignore"):
        for axis, (i, step) in enumerate(((c, x[1] - x[0]), (r, y[1] - y[0]))):
            if 0 < i < CELLS - 1:
                line = grid[r, i - 1:i + 2] if axis == 0 else grid[i - 1:i + 2, c]
                lo, mid, hi = np.log(line)
                curve = lo - 2 * mid + hi
                if np.isfinite(curve) and curve < 0:
                    out[axis] += step * float(np.clip(0.5 * (lo - hi) / curve, -0.5, 0.5))
    return out


def hpd_level(p: np.ndarray, mass: float) -> float:
    """The density threshold whose superlevel set holds `mass` of the cells' mass."""
    srt = np.sort(p)[::-1]
    return float(srt[min(int(np.searchsorted(np.cumsum(srt), mass)), srt.size - 1)])


def hpd_rings(box: Box, p: np.ndarray, mass: float) -> list[np.ndarray]:
    """Closed polygons around the cells holding `mass` (a zero border closes rings at the grid's edge)."""
    x, y, _ = box.cells()
    dx, dy = x[1] - x[0], y[1] - y[0]
    px = np.concatenate([[x[0] - dx], x, [x[-1] + dx]])
    py = np.concatenate([[y[0] - dy], y, [y[-1] + dy]])
    z = np.zeros((CELLS + 2, CELLS + 2))
    z[1:-1, 1:-1] = p.reshape(CELLS, CELLS)
    lines = contourpy.contour_generator(px, py, z).lines(hpd_level(p, mass))
    return [np.asarray(ring, float) for ring in lines if len(ring) >= 4]


def moment(box: Box, p: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The second moment (2, 2) of cells `p` on `box` about `point`, each cell's mass spread over its area."""
    x, y, _ = box.cells()
    gx, gy = np.meshgrid(x, y)
    d = np.column_stack([gx.ravel(), gy.ravel()]) - point
    spread = np.diag([(2 * box.hx / CELLS) ** 2 / 12, (2 * box.hy / CELLS) ** 2 / 12])
    return (d * p[:, None]).T @ d + spread * float(p.sum())


def summarise(box: Box, p: np.ndarray, point: np.ndarray | None = None, cov: np.ndarray | None = None) -> Region:
    """The region of cells `p` on `box`, about `point` (None: the cells' own mode), with the covariance `cov`
    where it was found more finely than these cells hold it (None: their moment about the point)."""
    x, y, _ = box.cells()
    gx, gy = np.meshgrid(x, y)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    point = mode(box, p) if point is None else point
    cov = moment(box, p, point) if cov is None else cov
    d = xy - point
    try:
        d2 = np.einsum("ci,ij,cj->c", d, np.linalg.inv(cov), d)
        held = {lvl: float(p[d2 <= chi2].sum()) for lvl, chi2 in zip(LEVELS, (ELLIPSE_50, ELLIPSE_95), strict=True)}
    except np.linalg.LinAlgError:
        held = {lvl: float("nan") for lvl in LEVELS}
    return Region(point, cov, {lvl: hpd_rings(box, p, lvl) for lvl in LEVELS}, held)


def size_text(metres: float) -> str:
    """A length as people read it: whole metres from 100 m on (1780, not 1.78e+03), three figures below."""
    return f"{metres:.0f}" if metres >= 100 else f"{metres:.3g}"
