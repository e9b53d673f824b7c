"""Reliability V's classes of bad input (issue 64), tried against the installed programs and the API: each line
says `held` or `broke` with what was seen. Kept for the next round's stress test.

    .venv/bin/python scripts/reliability_stress.py [--only NAME ...]

Each case runs in a temporary folder, in a few seconds (the big survey about a minute).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from aoa_localizer import BearingPoseInput, Input, Localizer, LocalizerConfig
from aoa_localizer.engine.geodesy import LocalFrame

PY = sys.executable


def run(*args, timeout=120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", *map(str, args)], capture_output=True, text=True, timeout=timeout, **kw)


def survey_csv(path: Path, ids, places=((47.0, 8.0, 45), (47.0, 8.01, 315), (46.99, 8.005, 10))) -> Path:
    rows = ["time,lat,lon,azimuth_deg,station,id"]
    t = 1_700_000_000
    for ident in ids:
        for k, (lat, lon, az) in enumerate(places):
            rows.append(f"{t},{lat},{lon},{az},s{k},{ident}")
            t += 60
    path.write_text("\n".join(rows) + "\n")
    return path


def quaternions(tmp: Path) -> str:
    """A pose bag whose quaternions are x1.02 gives the unit ones' estimate; x2 is refused as bad_azimuth."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from aoa_localizer.simulation.scenarios import simulate
    from msgs_adapters import build
    from msgs_adapters.bag import typestore

    data, ts = simulate("seed", 0), typestore()
    T = build.rosbags_types(ts)
    finals = {}
    for scale in (1.0, 1.02, 2.0):
        bag = tmp / f"q{scale}"
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            fix = w.add_connection("/gps/fix", "sensor_msgs/msg/NavSatFix", typestore=ts)
            df = w.add_connection("/df/bearing", "geometry_msgs/msg/PoseWithCovarianceStamped", typestore=ts)
            rows = [(f[0], fix, "sensor_msgs/msg/NavSatFix", build.navsatfix(T, *f[:4])) for f in data.fixes]
            for b in data.bearings:
                pose = build.pose_bearing(T, b[0], math.radians(90.0 - b[1]), math.radians(1.1) ** 2)
                q = pose.pose.pose.orientation
                q.z, q.w = q.z * scale, q.w * scale
                rows.append((b[0], df, "geometry_msgs/msg/PoseWithCovarianceStamped", pose))
            for stamp, conn, kind, msg in sorted(rows, key=lambda r: r[0]):
                w.write(conn, int(stamp * 1e9), ts.serialize_cdr(msg, kind))
        res = run("aoa_localizer.replay", bag, "--offline", "--seed", 1, "--output", tmp / f"q{scale}.jsonl")
        lines = (tmp / f"q{scale}.jsonl").read_text().splitlines() if (tmp / f"q{scale}.jsonl").exists() else []
        finals[scale] = (json.loads(lines[-1]) if len(lines) > 1 else None, res.stderr)
    unit, near, far = finals[1.0][0], finals[1.02][0], finals[2.0]
    ok = (unit and near and math.hypot(unit["east"] - near["east"], unit["north"] - near["north"]) < 0.01
          and "bad_azimuth" in far[1])
    refused = "bad_azimuth" in far[1]
    return f"{'held' if ok else 'broke'}: x1.02 same place: {bool(unit and near)}; x2 refused: {refused}"


def pose_variance(_tmp: Path) -> str:
    loc = Localizer(LocalizerConfig(seed=1, datum_lat=47.0, datum_lon=8.0))
    loc.add_fix(0.0, 47.0, 8.0)
    for k, var in enumerate((math.inf, -1.0, 0.0, math.nan)):
        loc.feed(Input("bearing_pose", BearingPoseInput(1.0 + k, 0.3, var)))
    refused = loc.view(light=True).rejected.get("bad_sigma", 0)
    loc.close()
    return f"{'held' if refused == 2 else 'broke'}: variance inf and -1 refused as bad_sigma ({refused} of 2)"


def antimeridian(tmp: Path) -> str:
    import pymap3d

    target, out = (10.0, 180.0), []
    rows = ["time,lat,lon,azimuth_deg,station,id"]
    for k, heading in enumerate((45.0, 135.0, 225.0, 315.0)):
        lat, lon = pymap3d.vincenty.vreckon(*target, 1000.0, heading)
        lon = (float(lon) + 180.0) % 360.0 - 180.0
        az = pymap3d.geodetic2aer(*target, 0.0, float(lat), lon, 0.0)[0]
        rows.append(f"{1_700_000_000 + k * 60},{float(lat):.8f},{lon:.8f},{az:.4f},s{k},tx")
    (tmp / "d.csv").write_text("\n".join(rows) + "\n")
    for model in ("pooled", "filter"):
        run("aoa_localizer.locate", tmp / "d.csv", "--model", model, "--output", tmp / f"d_{model}.jsonl")
        fix = json.loads((tmp / f"d_{model}.jsonl").read_text().splitlines()[0])
        out.append(float(pymap3d.vincenty.vdist(fix["lat"], fix["lon"], *target)[0]))
    return f"{'held' if max(out) < 5.0 else 'broke'}: pooled {out[0]:.1f} m, filter {out[1]:.1f} m off"


def file_names(tmp: Path) -> str:
    ids = ["a/b", "a_b", "a:b", "a\\b", "A_B", "x" * 300, "t\x01", "u\x1f", "f1", "f2", "F1", "..", ".", "a b", "é"]
    res = run("aoa_localizer.locate", survey_csv(tmp / "n.csv", ids), "--report", tmp / "rep")
    cot = list((tmp / "rep").glob("emitter_*.cot"))
    parsed = sum(1 for f in cot if ET.fromstring(f.read_bytes()) is not None)
    ok = len(cot) == len(ids) == parsed and "Traceback" not in res.stderr
    return f"{'held' if ok else 'broke'}: {len(ids)} ids, {len(cot)} .cot files, {parsed} well-formed"


def big_survey(tmp: Path) -> str:
    rng = np.random.default_rng(1)
    frame = LocalFrame(47.0, 8.0, 0.0)
    rows = ["time,lat,lon,azimuth_deg,station,id"]
    for i in range(300):
        tx = rng.uniform(-20000, 20000, 2)
        for k in range(int(rng.integers(3, 7))):
            a = rng.uniform(0, 2 * np.pi)
            st = tx + rng.uniform(100, 700) * np.array([np.cos(a), np.sin(a)])
            az = np.degrees(np.arctan2(*(tx - st))) + rng.normal(0, 5)
            lat, lon, _ = frame.to_geodetic(*st)
            rows.append(f"{1_700_000_000 + 30 * len(rows)},{lat:.7f},{lon:.7f},{az % 360:.2f},s{i}_{k},id{i}")
    (tmp / "big.csv").write_text("\n".join(rows) + "\n")
    out = tmp / "big.jsonl"
    p = subprocess.Popen([PY, "-m", "aoa_localizer.locate", str(tmp / "big.csv"), "--output", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert p.stdout is not None
    p.stdout.readline()
    p.stdout.readline()  # the first id's row: its line is written
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    kept = len(out.read_text().splitlines()) if out.exists() else 0
    progress = sum("calibrating" in line for line in err.splitlines())
    ok = p.returncode == 130 and kept >= 1 and progress >= 1 and "Traceback" not in err
    return f"{'held' if ok else 'broke'}: SIGTERM after the first id: exit {p.returncode}, {kept} lines kept, " \
           f"{progress} progress lines"


def tak_never_reads(_tmp: Path) -> str:
    from aoa_localizer.common.cot import CotSender

    server = socket.create_server(("127.0.0.1", 0))
    sender = CotSender(f"tcp://127.0.0.1:{server.getsockname()[1]}")
    start = time.monotonic()
    for _ in range(500):
        sender.send(b"<event/>" * 20_000)
    took = time.monotonic() - start
    dropped = sender.dropped
    sender.close()
    server.close()
    return f"{'held' if took < 1.0 and dropped > 0 else 'broke'}: 500 sends in {took * 1000:.0f} ms, {dropped} dropped"


def special_bag_files(tmp: Path) -> str:
    from aoa_localizer.simulation.scenarios import simulate
    from msgs_adapters.bag import write_bag

    data, seen = simulate("seed", 1), []
    for kind in ("zero", "fifo"):
        bag = tmp / f"bag_{kind}"
        write_bag(bag, data.fixes, data.bearings)
        extra = bag / "extra_0.mcap"
        extra.symlink_to("/dev/zero") if kind == "zero" else os.mkfifo(extra)
        for program, args in (("replay", ["--offline", "--output", tmp / f"{kind}.jsonl"]),
                              ("report", ["--out", tmp / f"rep_{kind}"])):
            try:
                res = run(f"aoa_localizer.{program}", bag, *args, timeout=60)
                seen.append(res.returncode == 2 and "not a regular file" in res.stderr)
            except subprocess.TimeoutExpired:
                seen.append(False)
    return f"{'held' if all(seen) else 'broke'}: {sum(seen)} of {len(seen)} refused at once"


def cot_urls(_tmp: Path) -> str:
    bad = ["udp://127.0.0.1:99999", "udp://127.0.0.1:-1", "udp://host", "udp://user:pw@host:6969"]
    codes = [run("aoa_localizer.node", "--ros-args", "-p", f"cot_url:={u}", timeout=60).returncode for u in bad]
    return f"{'held' if codes == [2] * len(bad) else 'broke'}: start refused with exit {codes}"


def output_paths(tmp: Path) -> str:
    csv_path = survey_csv(tmp / "o.csv", ["tx"])
    (tmp / "file").write_text("x")
    tries = [("aoa_localizer.locate", csv_path, "--report", tmp / "file" / "rep"),
             ("aoa_localizer.locate", csv_path, "--report", "/proc/aoa_stress"),
             ("aoa_localizer.locate", csv_path, "--output", "/proc/self/mem"),
             ("aoa_localizer.kraken_bridge", "--url", "http://127.0.0.1:9/x", "--record", "/proc/aoa_stress")]
    results = [run(*t, timeout=60) for t in tries]
    ok = [r.returncode == 2 and "Traceback" not in r.stderr for r in results]
    return f"{'held' if all(ok) else 'broke'}: {sum(ok)} of {len(ok)} refused before any work, exit 2"


def tiny_sigma(_tmp: Path) -> str:
    frame = LocalFrame(47.0, 8.0, 0.0)
    places = {"a": (0.0, 0.0), "b": (600.0, 0.0), "c": (0.0, 800.0)}
    loc = Localizer(LocalizerConfig(seed=1))
    for name, (e, n) in places.items():
        loc.add_station(name, fixed=True, position=(*frame.to_geodetic(e, n)[:2],))
    for k in range(12):
        name = "abc"[k % 3]
        e, n = places[name]
        loc.add_bearing(k + 1.0, math.degrees(math.atan2(300 - e, 400 - n)) % 360, 80.0, station=name, sigma_deg=1e-6)
    try:
        loc.flush()
        loc.finish()
        raised = ""
    except Exception as exc:  # noqa: BLE001 - what is being tried
        raised = type(exc).__name__
    rejected = dict(loc.view(light=True).rejected)
    loc.close()
    ok = not raised and rejected == {"bad_sigma": 12}
    return f"{'held' if ok else 'broke'}: {raised or 'no exception'}, {rejected}"


def umask_mode(tmp: Path) -> str:
    run("aoa_localizer.locate", survey_csv(tmp / "u.csv", ["tx"]), "--output", tmp / "u.jsonl")
    mode = stat.S_IMODE((tmp / "u.jsonl").stat().st_mode)
    mask = os.umask(0)
    os.umask(mask)
    return f"{'held' if mode == 0o666 & ~mask else 'broke'}: output mode {mode:o} under umask {mask:03o}"


CASES = {"quaternions": quaternions, "pose_variance": pose_variance, "antimeridian": antimeridian,
         "file_names": file_names, "big_survey": big_survey, "tak_never_reads": tak_never_reads,
         "special_bag_files": special_bag_files, "cot_urls": cot_urls, "output_paths": output_paths,
         "tiny_sigma": tiny_sigma, "umask": umask_mode}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="*", choices=tuple(CASES), help="these cases only")
    args = parser.parse_args()
    broke = 0
    for name in args.only or CASES:
        with tempfile.TemporaryDirectory(prefix="aoa_stress_") as tmp:
            start = time.monotonic()
            try:
                line = CASES[name](Path(tmp))
            except Exception as exc:  # noqa: BLE001 - a case that cannot even be tried is a broken one
                line = f"broke: {type(exc).__name__}: {exc}"
            broke += line.startswith("broke")
            print(f"{name:<18} {line} ({time.monotonic() - start:.1f} s)", flush=True)
    return 1 if broke else 0


if __name__ == "__main__":
    sys.exit(main())
