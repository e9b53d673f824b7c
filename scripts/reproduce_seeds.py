"""Reproduce the seed papers' tables on their own benchmark models and print ours next to theirs.

    python scripts/reproduce_seeds.py                 # the papers' run counts
    python scripts/reproduce_seeds.py --runs 10 --json seeds.json

RMSE: at each step k the root mean square error over the runs, then the mean over the steps (the
papers' "mean RMSE"); for the coordinated-turn model per position axis, for the truck-trailer per state.
UPF-DE's and AGA-PF's tables give the mean (and variance, maximum) over runs of each run's RMSE over
time: those cells are scored that way. Run r uses data seed r and
filter seed 1000 + r, so every filter sees the same data. The bootstrap rows ("pf") resample at every
step, as the papers' PF does; GFA-PF resamples when N_eff < N/2 and reads its distances in state units.
JSON: {"meta": {...}, "rows": [{paper, table, model, algorithm, N, metric, ours, paper_value}, ...]}.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from aoa_localizer.models import benchmarks as B
from aoa_localizer.simulation.evaluation import run_model

# Per algorithm, how the table runs it (LocalizerConfig changes).
SETTINGS = {"pf": ("sir", {"ess_threshold": 1.0}), "espf": ("espf", {}),
            "gfapf": ("gfapf", {"gfapf.scale": "absolute"}), "upfde": ("upfde", {}), "upf": ("upf", {}),
            "pfde": ("pfde", {}), "agapf": ("agapf", {})}


@dataclass
class Cell:
    """One table cell group: a model run by one algorithm with one N; metrics are filled from the runs."""

    paper: str
    table: str
    model: str
    make: object
    algorithm: str
    n: int
    steps: int
    runs: int
    paper_values: dict  # metric -> the paper's number (None where it gives none)
    jump: tuple | None = None
    changes: dict = field(default_factory=dict)
    per_run: bool = False  # RMSE over time per run, then mean (and variance, max) over runs
    transform: object = None  # maps states before scoring (the truck-trailer's derived x1)
    curve: np.ndarray | None = None  # RMSE of the first state at each k, filled by run_cell


def cells(runs_override: int | None) -> list[Cell]:
    r = lambda paper_runs: runs_override or paper_runs  # noqa: E731
    out = []
    for model, make, values in (("Model 1 (Gamma)", B.espf_model1, {"pf": 0.1135, "espf": 0.0788}),
                                ("Model 2 (UNGM)", B.espf_model2, {"pf": 3.6609, "espf": 3.6180})):
        for algo in ("pf", "espf"):
            out.append(Cell("espf", "Table 1", model, make, algo, 200, 60, r(50), {"rmse": values[algo]}))
    table2 = {200: {"pf": (0.3370, 0.4170), "espf": (0.2748, 0.3268)},
              500: {"pf": (0.3161, 0.3417), "espf": (0.2526, 0.2852)},
              800: {"pf": (0.2951, 0.3277), "espf": (0.2456, 0.2661)}}
    for n, values in table2.items():
        for algo in ("pf", "espf"):
            px, py = values[algo]
            out.append(Cell("espf", "Table 2", "Model 3 (coordinated turn)", B.espf_model3, algo, n, 60, r(50),
                            {"rmse_x": px, "rmse_y": py}))
    # Round 1's selection (the N largest of the pool, ties by position) beside the default draw by weight.
    out.append(Cell("espf", "top-N selection (round 1)", "Model 1 (Gamma)", B.espf_model1, "espf", 200, 60, r(50),
                    {"rmse": None}, changes={"espf.selection": "top"}))
    out.append(Cell("espf", "top-N selection (round 1)", "Model 3 (coordinated turn)", B.espf_model3, "espf", 200,
                    60, r(50), {"rmse_x": None, "rmse_y": None}, changes={"espf.selection": "top"}))
    for lam in (0.0, 2.0, 10.0, 50.0):
        for model, make in (("Model 1 (Gamma)", B.espf_model1), ("Model 2 (UNGM)", B.espf_model2)):
            out.append(Cell("espf", f"SBX lambda = {lam:g} (ours)", model, make, "espf", 200, 60, r(50),
                            {"rmse": None}, changes={"espf.sbx_lambda": lam}))
    for rv, values in ((0.1, {"pf": 2.772, "gfapf": 0.509}), (0.001, {"pf": 2.182, "gfapf": 0.122})):
        for algo in ("pf", "gfapf"):
            out.append(
                Cell(
                    "gfapf",
                    "Table 2",
                    f"Model 1 (Gamma), sigma_v^2 = {rv:g}",
                    lambda rv=rv: B.gfapf_model1(rv),
                    algo,
                    50,
                    100,
                    r(50),
                    {"rmse": values[algo], "time_s": None},
                )
            )
    for algo, value in (("pf", None), ("gfapf", 0.2031)):
        out.append(
            Cell("gfapf", "Table 3", "UNGM", B.gfapf_ungm, algo, 50, 100, r(50), {"rmse": value, "time_s": None})
        )
    for algo, value in (("pf", 1.8828), ("gfapf", 0.5825)):
        out.append(
            Cell(
                "gfapf",
                "Table 4",
                "UNGM, state jump of 10 at k = 25",
                B.gfapf_ungm,
                algo,
                50,
                100,
                r(50),
                {"rmse": value, "time_s": None},
                jump=(25, 10.0),
            )
        )
    upfde = {
        "pf": (0.9485, 0.0324, 0.0348),
        "pfde": (0.8054, 0.0320, 0.3088),
        "upf": (0.4893, 0.0100, 0.3742),
        "upfde": (0.2580, 0.0084, 0.6372),
    }
    for algo, (mean, var, secs) in upfde.items():
        out.append(
            Cell(
                "upfde",
                "Tables 1-2",
                "Gamma model, switch at t = 30",
                B.upfde_model,
                algo,
                10,
                50,
                r(500),
                {"rmse": mean, "rmse_var": var, "time_s": secs},
                per_run=True,
            )
        )
    for algo in upfde:  # the other reading of Gamma(3, 2): shape 3, scale 2 (Matlab's gamrnd)
        out.append(Cell("upfde", "Tables 1-2, Gamma(3, 2) as shape 3, scale 2", "Gamma model, switch at t = 30",
                        lambda: B.upfde_model("scale"), algo, 10, 50, r(500),
                        {"rmse": upfde[algo][0], "rmse_var": upfde[algo][1], "time_s": None}, per_run=True))
    for gamma in ("rate", "scale"):  # round 1's DE fitness, the importance ratio L p / q
        out.append(Cell("upfde", f"de.fitness: ratio (round 1), Gamma as {gamma}", "Gamma model, switch at t = 30",
                        lambda g=gamma: B.upfde_model(g), "upfde", 10, 50, r(500),
                        {"rmse": None, "rmse_var": None, "time_s": None}, per_run=True,
                        changes={"de.fitness": "ratio"}))
    out.append(
        Cell(
            "upfde",
            "Tables 1-2",
            "Gamma model, switch at t = 30",
            B.upfde_model,
            "pf",
            200,
            50,
            r(500),
            {"rmse": 0.4398, "rmse_var": None, "time_s": 0.6284},
            per_run=True,
        )
    )
    aga = {False: {100: 1.01, 300: 0.82, 500: 0.71}, True: {100: 4.02, 300: 3.90, 500: 3.46}}
    for jumped, values in aga.items():
        for n, value in values.items():
            for algo in ("pf", "agapf"):
                out.append(
                    Cell(
                        "agapf",
                        "Table 3" if jumped else "Table 2",
                        "1-D model" + (", state jump of 10 at k = 50" if jumped else ""),
                        B.agapf_ungm,
                        algo,
                        n,
                        100,
                        r(20),
                        {"rmse": value if algo == "agapf" else None, "rmse_max": None},
                        jump=(50, 10.0) if jumped else None,
                        per_run=True,
                    )
                )
    truck = {"pf": (0.8126, 0.7696, 1.0642, 22.1793, 26.6928), "agapf": (0.6412, 0.6172, 0.7015, 2.2361, 2.1793)}
    for algo, values in truck.items():
        out.append(
            Cell(
                "agapf",
                "Table 4",
                "truck-trailer, jump of 20 m at k = 50",
                B.TruckTrailerModel,
                algo,
                300,
                100,
                r(20),
                {f"rmse_x{i}": v for i, v in enumerate(values)},
                jump=(50, np.array([0.0, 0.0, 20.0, 20.0])),
                transform=B.TruckTrailerModel.five,
            )
        )
    for algo in ("pf", "agapf"):
        out.append(
            Cell(
                "agapf",
                "bearings-only tracking (ours)",
                "Gordon 1993 model, 24 steps",
                B.BearingsOnlyModel,
                algo,
                300,
                24,
                r(20),
                {"rmse_x": None, "rmse_y": None},
            )
        )
    return out


def run_cell(c: Cell, bar) -> list[dict]:
    algorithm, changes = SETTINGS[c.algorithm]
    model = c.make()
    sq, seconds = [], []
    for run in range(c.runs):
        truth, est, t = run_model(
            model, algorithm, c.n, c.steps, run, 1000 + run, jump=c.jump, **{**changes, **c.changes}
        )
        sq.append((truth - est) ** 2)
        seconds.append(t)
        bar.update()
    if c.transform is not None:
        sq = [c.transform(np.sqrt(e)) ** 2 for e in sq]
    rmse_k = np.sqrt(np.mean(sq, axis=0))  # (steps, dim)
    c.curve = rmse_k[:, 0]  # the first state (x position for the turn model), for --plot
    ours = {"rmse": float(rmse_k[:, 0].mean()), "time_s": float(np.mean(seconds))}
    if c.per_run:
        per_run = np.sqrt(np.mean(np.array(sq)[:, :, 0], axis=1))
        ours.update(rmse=float(per_run.mean()), rmse_var=float(per_run.var()), rmse_max=float(per_run.max()))
    if model.dim == 4 and c.transform is None:
        ours.update(rmse_x=float(rmse_k[:, 0].mean()), rmse_y=float(rmse_k[:, 2].mean()))
    ours.update({f"rmse_x{i}": float(rmse_k[:, i].mean()) for i in range(rmse_k.shape[1])} if c.transform else {})
    return [
        {
            "paper": c.paper,
            "table": c.table,
            "model": c.model,
            "algorithm": c.algorithm,
            "N": c.n,
            "metric": metric,
            "ours": ours[metric],
            "paper_value": paper_value,
            "runs": c.runs,
        }
        for metric, paper_value in c.paper_values.items()
    ]


def plot_cells(plot_dir: Path, done: list[Cell]):
    """One figure per paper table, model and N: RMSE of the first state against k, one line per algorithm."""
    import re

    from aoa_localizer.reporting.plots import rmse_curves

    plot_dir.mkdir(parents=True, exist_ok=True)
    groups = {}
    for c in done:
        if "ours" in c.table:
            continue
        groups.setdefault((c.paper, c.table, c.model, c.n), []).append(c)
    for (paper, table, model, n), cs in groups.items():
        slug = re.sub(r"[^a-z0-9]+", "_", f"{paper} {table} {model} n{n}".lower()).strip("_")
        rmse_curves(
            plot_dir / f"{slug}.png",
            f"{paper} {table}: {model}, N = {n}, {cs[0].runs} runs",
            {c.algorithm: (np.arange(1, len(c.curve) + 1), c.curve) for c in cs},
            xlabel="k",
            ylabel="RMSE of x (first state)",
            log=False,
        )


def print_rows(rows):
    print("| paper | table | model | algorithm | N | metric | ours | paper |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        pv = "-" if r["paper_value"] is None else f"{r['paper_value']:g}"
        print(
            f"| {r['paper']} | {r['table']} | {r['model']} | {r['algorithm']} | {r['N']} | {r['metric']} | "
            f"{r['ours']:.4g} | {pv} |"
        )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, help="Monte Carlo runs per cell (default: each paper's own)")
    parser.add_argument(
        "--papers", nargs="+", default=["espf", "gfapf", "upfde", "agapf"], choices=["espf", "gfapf", "upfde", "agapf"]
    )
    parser.add_argument("--json", metavar="OUT", help="write the rows as JSON")
    parser.add_argument("--plot", metavar="DIR", help="write RMSE-against-k plots, one per table, model and N")
    args = parser.parse_args(argv)
    todo = [c for c in cells(args.runs) if c.paper in args.papers]
    t0 = time.time()
    rows = []
    with tqdm(total=sum(c.runs for c in todo), unit="run", file=sys.stderr) as bar:
        for c in todo:
            bar.set_description(f"{c.paper} {c.table}")
            rows += run_cell(c, bar)
    print_rows(rows)
    if args.plot:
        plot_cells(Path(args.plot), todo)
    meta = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "wall_s": round(time.time() - t0, 1),
    }
    print(f"\n{meta['wall_s']} s, {meta['machine']}, {meta['cores']} cores, {meta['date']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
