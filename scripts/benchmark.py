"""Benchmark the public scenarios (docs/interface.md) and the robustness cells: accuracy against the CRLB,
honesty of the ellipse, speed.

Public section: runs r = 0..runs-1 of each scenario (data seeded r, filters 10000 + r, so all filters see the
same data) through the engine with each filter, plus the `particles` package's bootstrap and IBIS filters on
the same observation points when it is installed (pip install -e '.[bench]'). Prints one table per scenario
and the AFSA paper's Table 1 next to ours for `seed`.

Robustness section (`--section robustness`): the cells of scenarios.robustness_cells() (uniform wild share
0-40 %, a consistent reflector, noise mis-stated by 0.5x/2x/4x, quality unknown), every filter with the
default configuration, and the robust batch maximum-likelihood reference (`batch-ml`). Columns: RMSE over the
oracle CRLB of the inlier readings, gross failures (> 10x CRLB), runs without an estimate, NEES, 95 % ellipse
coverage, time per run. `--jobs` runs cells in parallel processes.

Geometry section (`--section geometry`): the cells of scenarios.geometry_cells(), geometries unlike the public
scenarios' (a pass 30 m from the emitter, with and without a turn before it, an emitter 8 km off the road, a slow
walk with a 5 deg DF, a loop around the emitter, an emitter behind the start), scored as the robustness cells are,
beside `oracle-ml`: least squares over every inlier reading at the antenna's true place with its true sigma (no
points, GPS or clocks), the estimate the readings alone allow. `-p NAME=VALUE` changes the configuration of these
two sections (e.g. `-p obs_max_range_share=0`).
"""
from __future__ import annotations

import argparse
import datetime
import json
import logging
import multiprocessing
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
import particles_peers  # noqa: E402

from aoa_localizer import LocalizerConfig  # noqa: E402
from aoa_localizer.common.cli import param_changes  # noqa: E402
from aoa_localizer.core.spec import ConfigError  # noqa: E402
from aoa_localizer.engine.crlb import crlb_rmse  # noqa: E402
from aoa_localizer.engine.geodesy import azimuth_to_enu  # noqa: E402
from aoa_localizer.filters import REGISTRY  # noqa: E402
from aoa_localizer.simulation.evaluation import LARGE_ERROR_M, final_scores, run, run_batch_ml  # noqa: E402
from aoa_localizer.simulation.scenarios import SCENARIOS, geometry_cells, robustness_cells, simulate  # noqa: E402

logging.getLogger("aoa_localizer").setLevel(logging.ERROR)  # per-run first-rejection notes would flood the table

# Every registered algorithm in its default (mcmc) variant and as its paper printed it, and AFSA's likelihood variant
FILTERS = {name: {"algorithm": name} for name in REGISTRY}
FILTERS["afsa-gaussian"] = {"algorithm": "afsa", "likelihood": "gaussian"}
FILTERS |= {f"{a.name}-paper": {"algorithm": a.name, f"{a.group}.variant": "paper"} for a in REGISTRY.values()}
PEERS = ("particles-bootstrap", "particles-ibis")
# AFSA paper, Table 1 (relative error x / y in %, seconds for 60 steps, "large errors" of 60 estimates).
# The paper's PF is the bootstrap filter: our `sir-paper` (sir's default is resample-move).
PAPER_TABLE1 = {"sir-paper": (0.266, 0.206, 0.183, 16), "afsa": (0.101, 0.091, 0.352, 6)}


def peer_runs(data, res, truth_engine, n, seed):
    """Run the particles peers on the points our filter used; returns {name: (estimates, step_s)}."""
    loc = res.localizer
    post = loc.posterior()
    points = post.used_points
    cfg = loc.config
    if cfg.has_prior:
        mean, cov = np.array([cfg.prior_east, cfg.prior_north]), cfg.prior_sigma_m**2 * np.eye(2)
        # The scenario prior is in the scenario frame; our engine frame may be shifted (datum = first fix).
        mean = mean + (truth_engine - data.emitter_enu)
    else:
        mean, cov = post.start_cloud.mean(axis=0), 2.0 * np.cov(post.start_cloud.T)
    out = {"particles-bootstrap": particles_peers.run_bootstrap(points, mean, cov, n, cfg.process_noise_m,
                                                                cfg.outlier_prob, seed),
           "particles-ibis": particles_peers.run_ibis(points, mean, cov, n, cfg.outlier_prob, seed)}
    return out


def peer_scores(estimates, step_s, truth_engine, crlb):
    err = np.array(estimates[-1]) - truth_engine
    errors = [float(np.hypot(*(np.array(e) - truth_engine))) for e in estimates]
    return {"converged": True, "error": float(np.hypot(*err)), "err_east": float(err[0]), "err_north": float(err[1]),
            "crlb": crlb, "large_errors": int(sum(e > LARGE_ERROR_M for e in errors)), "steps": len(estimates),
            "step_s": step_s, "errors": errors, "points": list(range(1, len(estimates) + 1))}


def aggregate(rows, truth) -> dict:
    ok = [r for r in rows if r["converged"]]
    if not ok:
        return {"runs": len(rows), "failed": len(rows)}
    err = np.array([r["error"] for r in ok])
    ex = np.array([r["err_east"] for r in ok])
    ey = np.array([r["err_north"] for r in ok])
    steps = np.concatenate([r["step_s"] for r in ok])
    crlb = float(np.sqrt(np.mean(np.square([r["crlb"] for r in ok]))))
    out = {
        "runs": len(rows), "failed": len(rows) - len(ok),
        "rmse_m": float(np.sqrt(np.mean(err**2))), "crlb_m": crlb,
        "rel_x_pct": float(100 * np.mean(np.abs(ex)) / abs(truth[0])),
        "rel_y_pct": float(100 * np.mean(np.abs(ey)) / abs(truth[1])),
        "bias_x_pct": float(100 * np.mean(ex) / truth[0]), "bias_y_pct": float(100 * np.mean(ey) / truth[1]),
        "large_errors_per_run": float(np.mean([r["large_errors"] for r in ok])),
        "steps_per_run": float(np.mean([r["steps"] for r in ok])),
        "step_median_ms": float(1e3 * np.median(steps)), "step_p95_ms": float(1e3 * np.percentile(steps, 95)),
        "step_mean_ms": float(1e3 * np.mean(steps)),
        "filter_total_ms": float(1e3 * np.mean([np.sum(r["step_s"]) for r in ok])),
    }
    out["rmse_over_crlb"] = out["rmse_m"] / crlb
    if "nees" in ok[0]:
        out["nees_mean"] = float(np.mean([r["nees"] for r in ok]))
        out["coverage95_pct"] = float(100 * np.mean([r["inside95"] for r in ok]))
        out["engine_wall_ms"] = float(1e3 * np.mean([r["wall_s"] for r in ok]))
    return out


def bench_scenario(name, runs, n, filters, with_peers, bar, scheduling="reproducible"):
    rows = {f: [] for f in filters}
    rows.update({p: [] for p in (PEERS if with_peers else ())})
    for r in range(runs):
        data = simulate(name, r)
        for fname in filters:
            cfg = LocalizerConfig(seed=10000 + r, num_particles=n, scheduling=scheduling).with_changes(**FILTERS[fname])
            res = run(data, cfg)
            s = dict(res.scores, step_s=res.step_s, wall_s=res.wall_s)
            rows[fname].append(s)
            if with_peers and fname == "afsa" and s["converged"]:
                frame = res.localizer.view(light=True).frame
                truth_engine = np.array(frame.to_enu(*data.emitter_lat_lon))
                for peer, (est, step_s) in peer_runs(data, res, truth_engine, n, 10000 + r).items():
                    rows[peer].append(peer_scores(est, step_s, truth_engine, s["crlb"]))
            bar.update()
    truth = SCENARIOS[name].emitter
    return {f: aggregate(v, truth) for f, v in rows.items() if v}, rows


def rmse_by_point(runs: list[dict], key: str = "errors"):
    """(point index, RMS over the runs that have an estimate at that point) for one filter."""
    by_point = {}
    for r in runs:
        for p, e in zip(r.get("points", []), r.get(key, []), strict=False):
            by_point.setdefault(p, []).append(e)
    pts = sorted(p for p, v in by_point.items() if len(v) >= max(1, len(runs) // 2))
    return np.array(pts), np.array([np.sqrt(np.mean(np.square(by_point[p]))) for p in pts])


def plot_scenarios(plot_dir: Path, raw: dict):
    from aoa_localizer.reporting.plots import rmse_curves

    plot_dir.mkdir(parents=True, exist_ok=True)
    for scenario, rows in raw.items():
        curves = {f: rmse_by_point(v) for f, v in rows.items() if v}
        ours = [v for f, v in rows.items() if f in FILTERS and v]
        bound = rmse_by_point(ours[0], "crlb_steps") if ours else None
        rmse_curves(plot_dir / f"{scenario}.png", f"{scenario}: RMSE over runs at each observation point, N = 100",
                    {f: c for f, c in curves.items() if len(c[0])}, bound)


def print_tables(results):
    cols = [("rmse_m", "RMSE m", "{:.2f}"), ("crlb_m", "CRLB m", "{:.2f}"), ("rmse_over_crlb", "xCRLB", "{:.2f}"),
            ("rel_x_pct", "relX %", "{:.3f}"), ("rel_y_pct", "relY %", "{:.3f}"),
            ("bias_x_pct", "biasX %", "{:+.3f}"), ("bias_y_pct", "biasY %", "{:+.3f}"),
            ("large_errors_per_run", ">15m/run", "{:.1f}"), ("nees_mean", "NEES", "{:.2f}"),
            ("coverage95_pct", "cov95 %", "{:.0f}"), ("step_median_ms", "med ms", "{:.3f}"),
            ("step_p95_ms", "p95 ms", "{:.3f}"), ("step_mean_ms", "mean ms", "{:.3f}"),
            ("filter_total_ms", "run ms", "{:.1f}"), ("failed", "fail", "{}")]
    for scenario, by_filter in results.items():
        print(f"\n## {scenario}")
        print("| filter | " + " | ".join(c[1] for c in cols) + " |")
        print("|---" * (len(cols) + 1) + "|")
        for fname, m in by_filter.items():
            cells = [fmt.format(m[k]) if k in m else "-" for k, _, fmt in cols]
            print(f"| {fname} | " + " | ".join(cells) + " |")
    ratios = [
        (
            sc,
            m["afsa"]["step_mean_ms"] / m["particles-ibis"]["step_mean_ms"],
            m["afsa"]["step_median_ms"] / m["particles-ibis"]["step_median_ms"],
        )
        for sc, m in results.items()
        if "afsa" in m and "particles-ibis" in m and "step_mean_ms" in m["afsa"]
    ]
    if ratios:
        print(
            "\nAFSA-PF time / particles IBIS time, same runs: "
            + ", ".join(f"{sc} {mean:.2f} (mean step), {med:.2f} (median step)" for sc, mean, med in ratios)
        )
    if "seed" in results:
        print("\n## AFSA paper Table 1 (Matlab, i5-2450M) next to ours on `seed`")
        print(
            "| filter | paper relX % | ours | paper relY % | ours | paper s / 60 steps | ours (filter) "
            "| paper >15 m of 60 | ours |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        for fname, (px, py, pt, pl) in PAPER_TABLE1.items():
            m = results["seed"].get(fname)
            if m and "rmse_m" in m:
                ours_t = m["filter_total_ms"] / 1e3 * 60 / m["steps_per_run"]
                print(
                    f"| {fname} | {px} | {m['rel_x_pct']:.3f} | {py} | {m['rel_y_pct']:.3f} | {pt} | {ours_t:.4f} | "
                    f"{pl} | {m['large_errors_per_run']:.1f} |"
                )


ROBUST_FILTERS = (*REGISTRY, "batch-ml")
ORACLE = "oracle-ml"  # the geometry section's yardstick (oracle_ml)
GROSS_FACTOR = 10.0
CELLS = {"robustness": robustness_cells, "geometry": geometry_cells}  # the sections scored cell by cell


def robust_task(task):
    """One (section, cell, run, filter): the final estimate's scores and the run's wall time."""
    section, cell, r, fname, scheduling, changes = task
    logging.getLogger("aoa_localizer").setLevel(logging.ERROR)
    warnings.simplefilter("ignore")  # numpy RuntimeWarnings of diverging peers must not break the progress bar
    data = simulate(CELLS[section]()[cell], r)
    cfg = LocalizerConfig(seed=10000 + r, scheduling=scheduling).with_changes(**changes)
    if fname == "batch-ml":
        return cell, fname, run_batch_ml(data, cfg)
    if fname == ORACLE:
        return cell, fname, oracle_ml(data)
    res = run(data, cfg.with_changes(algorithm=fname))
    s = res.scores
    out = {k: s[k] for k in ("converged", "crlb", "error", "nees", "inside95") if k in s}
    out["wall_s"] = res.wall_s
    return cell, fname, out


def oracle_ml(data) -> dict:
    """Least squares over the inlier readings at the antennas' true places with their true sigmas, from the truth,
    scored as a final estimate (its covariance the Gauss-Newton inverse at the optimum); wall time 0."""
    inlier = ~data.wild
    places, sigma = data.sensor_enu[inlier], data.sigma[inlier]
    north = data.frame.north_angle(*data.frame.to_geodetic(places[:, 0], places[:, 1])[:2])
    theta = azimuth_to_enu(data.bearings[inlier, 1], north)

    def residuals(x):
        return np.angle(np.exp(1j * (theta - np.arctan2(x[1] - places[:, 1], x[0] - places[:, 0])))) / sigma

    fit = least_squares(residuals, data.emitter_enu)
    cov = np.linalg.inv(fit.jac.T @ fit.jac)
    bound = crlb_rmse(data.emitter_enu, places, sigma)
    return {**final_scores(fit.x - data.emitter_enu, cov, bound), "wall_s": 0.0}


def robust_aggregate(rows: list[dict]) -> dict:
    ok = [r for r in rows if r["converged"]]
    out = {
        "runs": len(rows),
        "no_estimate": len(rows) - len(ok),
        "time_ms": float(1e3 * np.mean([r["wall_s"] for r in rows])),
    }
    if ok:
        err = np.array([r["error"] for r in ok])
        crlb = np.array([r["crlb"] for r in ok])
        out.update(
            rmse_over_crlb=float(np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(crlb**2))),
            median_over_crlb=float(np.median(err / crlb)),
            gross=int(np.sum(err > GROSS_FACTOR * crlb)),
            nees_mean=float(np.mean([min(r["nees"], 1e6) for r in ok])),
            nees_median=float(np.median([r["nees"] for r in ok])),
            coverage95_pct=float(100 * np.mean([r["inside95"] for r in ok])),
        )
    return out


def bench_robustness(runs: int, filters, jobs: int, scheduling: str = "reproducible", section: str = "robustness",
                     changes: dict | None = None) -> dict:
    cells = list(CELLS[section]())
    tasks = [(section, c, r, f, scheduling, changes or {}) for c in cells for r in range(runs) for f in filters]
    rows = {c: {f: [] for f in filters} for c in cells}
    with tqdm(total=len(tasks), unit="run", file=sys.stderr, desc=section) as bar:
        if jobs > 1:
            with multiprocessing.get_context("spawn").Pool(jobs) as pool:
                for cell, fname, out in pool.imap_unordered(robust_task, tasks, chunksize=4):
                    rows[cell][fname].append(out)
                    bar.update()
        else:
            for task in tasks:
                cell, fname, out = robust_task(task)
                rows[cell][fname].append(out)
                bar.update()
    return {c: {f: robust_aggregate(v) for f, v in by.items()} for c, by in rows.items()}


def print_robustness(results: dict, section: str = "robustness"):
    cols = [
        ("rmse_over_crlb", "RMSE/CRLB", "{:.2f}"),
        ("median_over_crlb", "median/CRLB", "{:.2f}"),
        ("gross", "gross", "{}"),
        ("no_estimate", "no est.", "{}"),
        ("nees_mean", "NEES mean", "{:.2f}"),
        ("nees_median", "NEES med.", "{:.2f}"),
        ("coverage95_pct", "cov95 %", "{:.0f}"),
        ("time_ms", "ms/run", "{:.0f}"),
        ("runs", "runs", "{}"),
    ]
    filters = list(next(iter(results.values())))
    for fname in filters:
        print(f"\n## {section}: {fname}")
        print("| cell | " + " | ".join(c[1] for c in cols) + " |")
        print("|---" * (len(cols) + 1) + "|")
        for cell, by in results.items():
            m = by[fname]
            print(f"| {cell} | " + " | ".join(fmt.format(m[k]) if k in m else "-" for k, _, fmt in cols) + " |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=100, help="Monte Carlo runs per scenario (default 100)")
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    parser.add_argument(
        "--filters",
        nargs="+",
        default=list(FILTERS),
        choices=list(FILTERS),
        help="filters to run (the robustness section also always runs the batch-ml reference)",
    )
    parser.add_argument("--particles", type=int, default=100, help="N for every filter (default 100)")
    parser.add_argument("--no-peers", action="store_true", help="skip the particles package's filters")
    parser.add_argument("--json", metavar="OUT", help="write all figures as JSON")
    parser.add_argument("--plot", metavar="DIR", help="write RMSE-against-step plots with the CRLB, one per scenario")
    parser.add_argument(
        "--section",
        choices=("public", "robustness", "geometry", "all"),
        default="all",
        help="public scenarios, robustness cells, or both (default); geometry: our own geometries' cells",
    )
    parser.add_argument(
        "--scheduling",
        choices=("reproducible", "realtime"),
        default="reproducible",
        help="the engine's scheduling (realtime: checks in the worker process, paced as a receiver; default "
        "reproducible)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=os.cpu_count() or 1,
        help="parallel processes for the robustness and geometry sections (default: the cores)",
    )
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                        help="robustness and geometry sections: a LocalizerConfig change (as the programs' -p)")
    args = parser.parse_args(argv)
    if args.param and args.section not in CELLS:
        parser.error("-p applies to --section robustness or geometry")
    try:
        LocalizerConfig().with_changes(**param_changes(args.param))
    except ConfigError as exc:
        parser.error(str(exc))
    if args.section in CELLS:
        return robustness_main(args)
    with_peers = particles_peers.AVAILABLE and not args.no_peers
    if not particles_peers.AVAILABLE and not args.no_peers:
        print(
            "note: the `particles` package is not installed (pip install -e '.[bench]'): no peer rows", file=sys.stderr
        )
    t0 = time.time()
    results, raw = {}, {}
    # numpy's RuntimeWarnings of diverging filters would break into the progress bar: counted, told after it.
    with warnings.catch_warnings(record=True) as caught, tqdm(
        total=args.runs * len(args.scenarios) * len(args.filters), unit="run", file=sys.stderr
    ) as bar:
        warnings.simplefilter("always", RuntimeWarning)
        for name in args.scenarios:
            bar.set_description(name)
            results[name], raw[name] = bench_scenario(name, args.runs, args.particles, args.filters, with_peers, bar,
                                                        args.scheduling)
    if caught:
        kinds = sorted({str(w.message) for w in caught})
        print(f"note: {len(caught)} numpy RuntimeWarnings during the runs (diverging filters): {'; '.join(kinds[:5])}",
              file=sys.stderr)
    print_tables(results)
    if args.plot:
        plot_scenarios(Path(args.plot), raw)
    meta = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "runs": args.runs,
        "particles": args.particles,
        "wall_s": round(time.time() - t0, 1),
    }
    print(
        f"\n{meta['runs']} runs per scenario, N = {args.particles}, {meta['wall_s']} s, {meta['machine']}, "
        f"{meta['cores']} cores, {meta['date']}"
    )
    robust = {}
    if args.section == "all":
        robust = bench_robustness(
            args.runs, [f for f in ROBUST_FILTERS if f in args.filters or f == "batch-ml"], args.jobs, args.scheduling
        )
        print_robustness(robust)
    if args.json:
        Path(args.json).write_text(json.dumps({"meta": meta, "results": results, "robustness": robust}, indent=1))


def robustness_main(args):
    t0 = time.time()
    filters = [f for f in ROBUST_FILTERS if f in args.filters or f == "batch-ml"]
    if args.section == "geometry":
        filters.append(ORACLE)
    robust = bench_robustness(args.runs, filters, args.jobs, args.scheduling, args.section, param_changes(args.param))
    print_robustness(robust, args.section)
    meta = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "runs": args.runs,
        "jobs": args.jobs,
        "changes": param_changes(args.param),
        "wall_s": round(time.time() - t0, 1),
    }
    print(f"\n{args.runs} runs per cell, {meta['wall_s']} s, {meta['machine']}, {meta['cores']} cores, {meta['date']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"meta": meta, args.section: robust}, indent=1))


if __name__ == "__main__":
    main()
