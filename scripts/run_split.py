"""Where a whole run's time goes: the start searches, the global checks (in the calls and the end of data's), the
moves (resampling's sweeps, the modes' and start's moves) and the rest (the readings' intake and the filter's
steps), beside Stone Soup's EKF on the same readings in the same process (issue "predictable cost";
docs/benchmarks.md has the figures).

    python scripts/run_split.py [--runs 3] [--cases seed,straight,urban,homing,ring,wild20]

Ours runs the default configuration (N = 100, `scheduling: reproducible`) through `feed`, `flush` and `finish`,
as scripts/peer_speed.py does. The parts are timed by wrapping the engine's functions that make them (a search's
or check's turns wherever they ran; nested parts are counted once, in the outer). The columns `without ...` give the
run's cost with those parts taken off, as a share of the EKF's whole run: what the rest of the design costs if the
global work were free. Nothing here is a test.
"""
from __future__ import annotations

import argparse
import functools
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import peer_speed  # noqa: E402

from aoa_localizer import Localizer, LocalizerConfig  # noqa: E402
from aoa_localizer.engine.inference import checks  # noqa: E402
from aoa_localizer.engine.scheduling import slices  # noqa: E402
from aoa_localizer.engine.track import initiator, supervisor  # noqa: E402
from aoa_localizer.filters.base import ParticleFilter  # noqa: E402
from aoa_localizer.filters.resample_move import ResampleMove  # noqa: E402
from aoa_localizer.simulation.evaluation import scenario_config  # noqa: E402
from aoa_localizer.simulation.scenarios import simulate  # noqa: E402

SPENT: defaultdict[str, float] = defaultdict(float)
COUNT: defaultdict[str, int] = defaultdict(int)
_open: list[str] = []  # the parts being timed now, outermost first: a nested part is its outer's


def _timing(name: str, t0: float):
    if _open == [name]:
        SPENT[name] += time.perf_counter() - t0


def _timed_job(name: str, fn: Callable) -> Callable:
    """A job's function: timed here when it runs in the caller (inline, the end of data); in its own thread (made in
    turns, slices.py) its turns are timed where they are given (_timed_turns), the thread only names the part."""
    timed = _timed_call(name, fn)

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        turns = getattr(slices._meter, "turns", None)
        if turns is None:
            return timed(*args, **kwargs)
        COUNT[name] += 1
        turns.part = name
        return fn(*args, **kwargs)
    return wrapped


def _timed_turns(give: Callable) -> Callable:
    """`_Turns.give`, each turn timed under the part its job named."""
    @functools.wraps(give)
    def wrapped(turns, call, whole):
        t0 = time.perf_counter()
        try:
            return give(turns, call, whole)
        finally:
            name = getattr(turns, "part", "")
            if name and not _open:
                SPENT[name] += time.perf_counter() - t0
    return wrapped


def _timed_call(name: str, fn: Callable) -> Callable:
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        COUNT[name] += 1
        _open.append(name)
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            _timing(name, t0)
            _open.pop()
    return wrapped


def instrument():
    """Wrap the functions that make each part (the modules that call them hold their own names)."""
    checks.search_start = initiator.search_start = _timed_job("start searches", checks.search_start)
    checks.run_check = supervisor.run_check = _timed_job("global checks", checks.run_check)
    slices._Turns.give = _timed_turns(slices._Turns.give)
    ResampleMove.move = _timed_call("moves", ResampleMove.move)
    ParticleFilter.rejuvenate = _timed_call("moves", ParticleFilter.rejuvenate)


PARTS = ("start searches", "global checks", "moves")


def split(case: str, r: int) -> dict[str, float]:
    """One run of `case` (data seed r): each part's seconds and count, the whole run's, and the EKF's."""
    data = simulate(peer_speed.CASES[case], r)
    SPENT.clear()
    COUNT.clear()
    loc = Localizer(scenario_config(data, LocalizerConfig(seed=10000 + r)))
    t0 = time.perf_counter()
    for event in data.inputs():
        loc.feed(event)
    loc.flush()
    loc.finish()
    whole = time.perf_counter() - t0
    loc.close()
    post = loc.posterior()
    start = post.start_cloud if post is not None else None
    assert start is not None, f"{case} {r}: the filter never started"
    prior = (peer_speed.in_scenario_frame(loc, data, start.mean(axis=0)), 2.0 * np.cov(start.T))
    ekf, _, _ = peer_speed.stone_soup(data, prior, 0, 10000 + r)
    out = {"readings": float(len(data.bearings)), "whole": whole, "ekf": ekf}
    for part in PARTS:
        out[part], out[part + " n"] = SPENT[part], float(COUNT[part])
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3, help="data seeds 0..runs-1 of each case")
    parser.add_argument("--cases", default="seed,straight,urban,homing,ring,wild20")
    args = parser.parse_args(argv)
    if peer_speed.Cartesian2DToBearing is None:
        print("Stone Soup is needed (pip install -e '.[bench]')", file=sys.stderr)
        return 2
    cases = args.cases.split(",")
    unknown = [c for c in cases if c not in peer_speed.CASES]
    if unknown:
        print(f"unknown case(s) {', '.join(unknown)}; known: {', '.join(peer_speed.CASES)}", file=sys.stderr)
        return 2
    instrument()
    split(cases[0], args.runs)  # untimed: every method's first calls in the process
    print(f"| case | readings | whole run (ms) | start searches (ms / how many) | global checks (ms / how many) | "
          f"moves (ms) | the rest (ms) | EKF (ms) | whole / EKF | without searches and checks / EKF | "
          f"the rest alone / EKF |  (mean of {args.runs} runs)")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for case in cases:
        runs = [split(case, r) for r in range(args.runs)]
        m = {k: float(np.mean([run[k] for run in runs])) for k in runs[0]}
        rest = m["whole"] - sum(m[p] for p in PARTS)
        free = m["whole"] - m["start searches"] - m["global checks"]
        print(f"| {case} | {m['readings']:.0f} | {1e3 * m['whole']:.0f} | "
              f"{1e3 * m['start searches']:.0f} / {m['start searches n']:.0f} | "
              f"{1e3 * m['global checks']:.0f} / {m['global checks n']:.0f} | {1e3 * m['moves']:.0f} | "
              f"{1e3 * rest:.0f} | {1e3 * m['ekf']:.0f} | {m['whole'] / m['ekf']:.2f} | {free / m['ekf']:.2f} | "
              f"{rest / m['ekf']:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
