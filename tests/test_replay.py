"""Offline replay as a user runs it: `python -m aoa_localizer.replay BAG --offline --output FILE`."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from aoa_localizer import LocalizerConfig
from aoa_localizer.evaluation import run
from aoa_localizer.geodesy import LocalFrame
from aoa_localizer.scenarios import SCENARIOS, Scenario, simulate
from msgs_adapters.bag import write_bag

ROOT = Path(__file__).resolve().parent.parent
REQUIRED = {"stamp", "lat", "lon", "east", "north", "cov", "bearings_used"}


def replay(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "aoa_localizer.replay", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=240)


def lines(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()]


@pytest.mark.parametrize("bag, extra", [("seed", []), ("urban", ["--params-file", ROOT / "bags/urban.params.yaml"])])
def test_sample_bags_localise(tmp_path, bag, extra):
    out = tmp_path / "est.jsonl"
    res = replay(ROOT / "bags" / bag, "--offline", "--output", out, "--seed", 1, *extra)
    assert res.returncode == 0, res.stderr
    est = lines(out)
    assert est and REQUIRED <= set(est[-1])
    sc = SCENARIOS[bag]
    e, n = LocalFrame(*sc.datum).to_enu(est[-1]["lat"], est[-1]["lon"])
    assert math.hypot(e - sc.emitter[0], n - sc.emitter[1]) < 10.0
    assert "error against the bag's truth" in res.stderr


def test_offline_replay_gives_the_engines_own_answer(tmp_path):
    data = simulate("homing", 3)
    write_bag(tmp_path / "bag", data.fixes, data.bearings, data.emitter_enu, data.scenario.datum)
    res = replay(tmp_path / "bag", "--offline", "--output", tmp_path / "e.jsonl", "--seed", 42, "--particles", 150)
    assert res.returncode == 0, res.stderr
    direct = run(data, LocalizerConfig(seed=42, num_particles=150)).estimates
    replayed = lines(tmp_path / "e.jsonl")
    assert len(replayed) == len(direct)
    assert replayed[-1]["east"] == pytest.approx(direct[-1].east, abs=1e-9)
    assert np.allclose(replayed[-1]["cov"], direct[-1].cov, rtol=0, atol=1e-9)


def test_truncated_bag_keeps_the_estimates_made_before_the_damage(tmp_path):
    long_drive = Scenario("long", (1200, 800), ((0, 0), (1000, 400), (1500, 600), (1600, 1400), (1500, 600),
                                                (1000, 400), (0, 0), (1000, 400), (1600, 1400)),
                          points=0, df_rate_hz=20.0, quality=(60.0, 100.0))
    data = simulate(long_drive, 0)
    write_bag(tmp_path / "bag", data.fixes, data.bearings)
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    raw = mcap.read_bytes()
    assert len(raw) > 2**20  # more than one 1 MiB chunk, so the first one survives the cut
    mcap.write_bytes(raw[: int(len(raw) * 0.8)])
    res = replay(tmp_path / "bag", "--offline", "--output", tmp_path / "e.jsonl")
    assert res.returncode == 1
    assert "damaged after" in res.stderr
    assert len(lines(tmp_path / "e.jsonl")) > 10


@pytest.mark.parametrize("make", ["garbage", "missing", "empty_dir"])
def test_unreadable_input_exits_non_zero_with_a_message(tmp_path, make):
    path = tmp_path / "bag"
    if make == "garbage":
        path.mkdir()
        (path / "bag.mcap").write_bytes(b"\x00not an mcap file" * 100)
    elif make == "empty_dir":
        path.mkdir()
    res = replay(path, "--offline", "--output", tmp_path / "e.jsonl")
    assert res.returncode == 2
    assert "replay:" in res.stderr


def test_invalid_parameter_is_refused(tmp_path):
    res = replay(ROOT / "bags/seed", "--offline", "--output", tmp_path / "e.jsonl", "-p", "quality_min=400")
    assert res.returncode == 2 and "quality_min" in res.stderr


def test_main_job_prints_the_estimate_and_its_error():
    res = subprocess.run([sys.executable, "-m", "aoa_localizer.simulate", "--scenario", "seed"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "estimate (afsa" in res.stdout and "Cramer-Rao bound" in res.stdout
