"""Run a simulated scenario through the Localizer and score it against the truth (benchmark and main job)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from aoa_localizer.engine.config import LocalizerConfig
from aoa_localizer.engine.crlb import crlb_rmse, crlb_so_far, inside_ellipse, nees
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.scheduling.memory import settle_process
from aoa_localizer.engine.types import Estimate
from aoa_localizer.filters import REGISTRY, make_filter
from aoa_localizer.simulation.fleet import FleetData
from aoa_localizer.simulation.scenarios import ScenarioData

LARGE_ERROR_M = 15.0  # the AFSA paper's "large error"


@dataclass
class RunResult:
    estimates: list[Estimate]
    step_s: list[float]  # filter update time per observation point
    localizer: Localizer
    wall_s: float = 0.0
    scores: dict = field(default_factory=dict)


def scenario_config(data: ScenarioData, base: LocalizerConfig) -> LocalizerConfig:
    """`base` with the scenario's own filter settings (prior, receiver calibration) applied."""
    return base.with_changes(**data.scenario.filter_overrides) if data.scenario.filter_overrides else base


def feed(loc: Localizer, data: ScenarioData) -> None:
    """A scenario's fixes and bearings into `loc` in stamp order, without the end of data (more may follow). Under
    `scheduling: realtime` each input waits for the worker and then makes the owed move sweeps, as a node does in
    the time a receiver's pace leaves between messages (Localizer.catch_up)."""
    for event in data.inputs():
        loc.feed(event)
        loc.catch_up()


def feed_fleet(loc: Localizer, data: FleetData) -> None:
    """Every station's fixes and DF records (with their frequencies) into `loc` in stamp order, as `feed` does for
    one vehicle."""
    for kind, station, row in data.events():
        if kind == "fix":
            loc.add_fix(row[0], row[1], row[2], row[3], station=station)
        else:
            loc.add_bearing(row[0], row[1], row[2], station=station, frequency_hz=row[3])
        loc.catch_up()


def run(data: ScenarioData, cfg: LocalizerConfig) -> RunResult:
    """Feed a scenario's fixes and bearings in stamp order, flush and finish at the end, keep every estimate."""
    settle_process()  # a benchmark's process: freed memory reused, BLAS on one thread (scheduling/memory.py)
    loc = Localizer(scenario_config(data, cfg))
    estimates, step_s = [], []

    def keep(est):
        if est is not None:
            estimates.append(est)
            step_s.append(loc.view(light=True).track.update_s)

    t0 = time.perf_counter()
    for estimate in loc.run(data.inputs()):
        keep(estimate)
    result = RunResult(estimates, step_s, loc, wall_s=time.perf_counter() - t0)
    result.scores = score(data, result)
    return result


def run_batch_ml(data: ScenarioData, cfg: LocalizerConfig) -> dict:
    """The robust batch ML reference: the same pairing and points as the Localizer, no filter, one estimate
    over all points (EmitterTrack.batch_estimate). Scored like a filter's final estimate."""
    big = 100_000  # the most points init_bearings allows: no filter ever starts on a benchmark run
    loc = Localizer(scenario_config(data, cfg).with_changes(init_bearings=big, init_max_points=big))
    t0 = time.perf_counter()
    feed(loc, data)
    loc.flush()  # no finish(): no filter runs; the batch estimate is the end-of-data search
    # the reference reads the track's held points directly: no filter runs, so no estimate leaves the face
    channel = loc._channel()
    mode = channel.batch_estimate() if channel is not None else None
    wall = time.perf_counter() - t0
    truth = data.emitter_enu
    bound = crlb_rmse(truth, data.sensor_enu[~data.wild], data.sigma[~data.wild])
    if mode is None:
        return {"converged": False, "crlb": bound, "wall_s": wall}
    frame = loc.view(light=True).frame
    assert frame is not None  # a mode comes from points, after the datum
    lat, lon, _ = frame.to_geodetic(mode.mean[0], mode.mean[1])
    err = np.array(data.frame.to_enu(lat, lon)) - truth
    return {**final_scores(err, mode.cov, bound), "wall_s": wall}


def final_scores(err: np.ndarray, cov, bound: float) -> dict:
    """A final estimate's scores: its error (m, and east/north), the bound, NEES and whether the 95 % ellipse holds
    the truth."""
    return {
        "converged": True,
        "error": float(np.hypot(*err)),
        "err_east": float(err[0]),
        "err_north": float(err[1]),
        "crlb": bound,
        "nees": nees(err, cov),
        "inside95": inside_ellipse(err, cov),
    }


def score(data: ScenarioData, result: RunResult) -> dict:
    """Final error, the CRLB of the inlier bearings, NEES, ellipse coverage, relative errors, large errors."""
    truth = data.emitter_enu
    inlier = ~data.wild
    bound = crlb_rmse(truth, data.sensor_enu[inlier], data.sigma[inlier])
    if not result.estimates:
        return {"converged": False, "crlb": bound}
    # Estimates come in the engine's frame (its datum may be the first fix): score through lat/lon.
    lat = np.array([e.lat for e in result.estimates])
    lon = np.array([e.lon for e in result.estimates])
    east, north = data.frame.to_enu(lat, lon)
    errors = np.hypot(east - truth[0], north - truth[1])
    final = result.estimates[-1]
    err = np.array([east[-1], north[-1]]) - truth
    return {
        **final_scores(err, final.cov, bound),
        "rel_x": float(abs(err[0]) / abs(truth[0])),
        "rel_y": float(abs(err[1]) / abs(truth[1])),
        "bias_x": float(err[0] / truth[0]),
        "bias_y": float(err[1] / truth[1]),
        "large_errors": int(np.sum(errors > LARGE_ERROR_M)),
        "steps": len(result.estimates),
        "errors": errors.tolist(),
        "points": [e.points_used for e in result.estimates],
        "crlb_steps": crlb_so_far(
            truth,
            data.sensor_enu[inlier],
            data.sigma[inlier],
            data.bearings[inlier, 0],
            [e.stamp for e in result.estimates],
        ).tolist(),
    }


def run_model(
    model,
    algorithm: str,
    n: int,
    steps: int,
    data_seed: int,
    filter_seed: int,
    jump: tuple[int, float] | None = None,
    **changes,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One run of a filter on a benchmark model: (true states x_1..x_T, estimates, filter seconds).

    Data from `data_seed`, the filter from `filter_seed`, so filters compared with the same seeds see the
    same data. The filter runs in its `paper` variant (the papers' models are where the printed filters
    belong) unless `changes` say otherwise; `changes` are LocalizerConfig fields (flat `group.name` keys).
    """
    x_true, zs = model.simulate(steps, np.random.default_rng(data_seed), jump)
    paper = {f"{REGISTRY[algorithm].group}.variant": "paper"}
    cfg = LocalizerConfig(algorithm=algorithm, num_particles=n, seed=filter_seed).with_changes(**paper, **changes)
    rng = np.random.default_rng(filter_seed)
    f = make_filter(cfg, rng, model)
    f.initialise(model.initial(n, rng))
    est = np.empty((steps, model.dim))
    t0 = time.perf_counter()
    for k, z in enumerate(zs):
        f.update(z)
        est[k] = f.estimate()[0]
    return x_true[1:], est, time.perf_counter() - t0
