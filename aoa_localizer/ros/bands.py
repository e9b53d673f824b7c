"""Several localizer nodes over one spectrum: the bands and namespaces `launch/spectrum.launch.py` starts them with
(docs/interface.md, "Several nodes over one spectrum")."""
from __future__ import annotations

import math
from itertools import pairwise

from aoa_localizer.engine.config import FREQUENCY_MAX_HZ


def band_nodes(edges: str) -> list[tuple[str, list[float]]]:
    """`edges` "f0,f1,...,fK" (Hz, ascending) as K (namespace, [low, high]) pairs: `band0` takes [f0, f1), `band1`
    [f1, f2), ... so every frequency from f0 to fK belongs to exactly one node. ValueError says what is wrong."""
    try:
        values = [float(part) for part in edges.split(",")]
    except ValueError:
        raise ValueError(f"edges must be frequencies in Hz separated by commas, got {edges!r}") from None
    if len(values) < 2:
        raise ValueError(f"edges needs at least two frequencies (one band), got {edges!r}")
    if not all(math.isfinite(v) and 0 <= v <= FREQUENCY_MAX_HZ for v in values):
        raise ValueError(f"edges must be in [0, {FREQUENCY_MAX_HZ:g}] Hz, got {edges!r}")
    if any(b <= a for a, b in pairwise(values)):
        raise ValueError(f"edges must increase, got {edges!r}")
    return [(f"band{i}", [low, high]) for i, (low, high) in enumerate(pairwise(values))]
