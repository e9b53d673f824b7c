"""Start the simulated vehicle (or a bag replay) and the localizer as separate processes, headless,
in an isolated ROS domain; print progress and the final estimate with its error; exit 0 when it converged.

    python -m aoa_localizer.launch --scenario urban --speedup 10 --record urban_bag
    python -m aoa_localizer.launch --bag bags/seed --rate 10 -p seed=3

Converged: the node published an estimate whose 95 % ellipse is under --max-ellipse metres and, when
the truth is known (sim/truth), whose error is inside that ellipse scaled by 3. Exit codes: 0
converged, 1 ran but did not converge (the reason is printed), 2 bad options or a process failed.
No process is left behind: children run in their own process groups and are stopped on every exit path.
"""
from __future__ import annotations

import argparse
import ctypes
import json
import math
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aoa_localizer.engine.crlb import ELLIPSE_95, ellipse_axes
from aoa_localizer.engine.crlb import nees as crlb_nees
from aoa_localizer.engine.scenarios import SCENARIOS

_PR_SET_PDEATHSIG = 1  # prctl option: a signal for this process when its parent dies

CONVERGE_SCALE = 3.0  # the truth must lie inside the 95 % ellipse scaled by this


class Stop(Exception):
    """SIGTERM or SIGINT to the launcher."""


class _StopOnce:
    """Signal handler: the first SIGINT or SIGTERM raises Stop; later ones (a second Ctrl-C while the children
    are being stopped) only say so, so the cleanup finishes instead of ending in a traceback."""

    def __init__(self):
        self.stopping = False

    def __call__(self, signum, frame):
        if self.stopping:
            print("launch: already stopping; the children get a few seconds to exit", file=sys.stderr)
            return
        self.stopping = True
        raise Stop(signal.Signals(signum).name)


def ros_value(v) -> str:
    """A Python value as a --ros-args -p value (YAML)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def parse_params(items) -> dict:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"launch: -p takes NAME=VALUE, got {item!r}")
        out[name.strip()] = value.strip()
    return out


def _die_with_parent():
    """In the child before exec (Linux): SIGTERM when the launcher dies, even by SIGKILL, so no node or vehicle
    is left running (elsewhere: nothing; the launcher's own cleanup still stops them on every other exit)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


class Child:
    """A child process in its own session, its output in a log file."""

    def __init__(self, name: str, cmd: list[str], env: dict, logdir: Path):
        self.name = name
        self.log_path = logdir / f"{name}.log"
        self.log = open(self.log_path, "w")
        self.proc = subprocess.Popen(cmd, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True,
                                     preexec_fn=_die_with_parent)

    def running(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout: float = 5.0) -> int | None:
        """SIGINT, then SIGTERM, then SIGKILL to the whole process group."""
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            if self.proc.poll() is not None:
                break
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                self.proc.wait(wait)
            except subprocess.TimeoutExpired:
                continue
        self.log.close()
        return self.proc.returncode

    def tail(self, n: int = 15) -> str:
        lines = self.log_path.read_text(errors="replace").splitlines()
        return "\n".join(f"  [{self.name}] {line}" for line in lines[-n:])


def build_commands(args, node_params: dict) -> tuple[list[str], list[str]]:
    py = sys.executable
    node = [py, "-m", "aoa_localizer.node", "--ros-args"]
    if args.params_file:
        node += ["--params-file", str(args.params_file)]
    for k, v in node_params.items():
        node += ["-p", f"{k}:={ros_value(v)}"]
    if args.bag:
        source = [py, "-m", "aoa_localizer.replay", str(args.bag), "--rate", str(args.rate),
                  "--topics", "/gps/fix", "/df/bearing", "/sim/truth", "/sim/datum"]
    else:
        source = [py, "-m", "aoa_localizer.sim_vehicle", "--ros-args", "-p", f"scenario:={args.scenario}",
                  "-p", f"speedup:={float(args.speedup)}", "-p", f"data_seed:={args.data_seed}",
                  "-p", f"wait_for_subscribers:={2 if args.record else 1}"]
        if args.duration:
            source += ["-p", f"duration_s:={float(args.duration)}"]
        for k, v in parse_params(args.vehicle_param).items():
            source += ["-p", f"{k}:={v}"]
    return node, source


def node_parameters(args) -> dict:
    """The scenario's frame and filter settings (so the node's map is the truth's), then the user's -p."""
    params = {}
    if not args.bag:
        sc = SCENARIOS[args.scenario]
        params.update(datum_lat=sc.datum[0], datum_lon=sc.datum[1], datum_alt=sc.datum[2])
        params.update(sc.filter_overrides)
    if args.seed is not None:
        params["seed"] = args.seed
    params.update(parse_params(args.param))
    return params


class Monitor:
    """The launcher's own node: follows emitter/pose, sim/truth, /diagnostics; records if asked."""

    def __init__(self, record: Path | None):
        import rclpy
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        from msgs_adapters.build import rclpy_types

        rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.rclpy = rclpy
        self.node = rclpy.create_node("aoa_launch")
        T = rclpy_types()
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pose = self.truth = self.diag = None
        self.node.create_subscription(T.PoseWithCovarianceStamped, "emitter/pose", lambda m: setattr(self, "pose", m), latched)
        self.node.create_subscription(T.PointStamped, "sim/truth", lambda m: setattr(self, "truth", m), latched)
        self.node.create_subscription(T.NavSatFix, "emitter/fix", lambda m: setattr(self, "fix", m), 10)
        self.node.create_subscription(T.DiagnosticArray, "/diagnostics", lambda m: setattr(self, "diag", m), 10)
        self.fix = None
        self.recorder = None
        if record is not None:
            from msgs_adapters.recorder import BagRecorder

            self.recorder = BagRecorder(self.node, record)

    def spin(self, seconds: float):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=min(0.05, max(0.0, end - time.monotonic())))
            if self.recorder:
                self.recorder.poll()

    def state(self) -> dict:
        from msgs_adapters.fields import diagnostics_values, estimate_from_pose

        out = {}
        if self.diag is not None:
            out["diag"] = diagnostics_values(self.diag).get("aoa_localizer: localizer", {})
        if self.pose is not None:
            stamp, east, north, cov = estimate_from_pose(self.pose)
            out.update(stamp=stamp, east=east, north=north, cov=cov)
        if self.fix is not None:
            out.update(lat=self.fix.latitude, lon=self.fix.longitude)
        if self.truth is not None:
            out["truth"] = (self.truth.point.x, self.truth.point.y)
        return out

    def close(self):
        if self.recorder:
            self.recorder.close()
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def verdict(state: dict, max_ellipse: float) -> tuple[bool, str, dict]:
    """Converged or not, why, and the figures."""
    if "east" not in state:
        status = state.get("diag", {}).get("status", "no diagnostics received")
        return False, f"no estimate was published ({status})", {}
    cov = np.array(state["cov"])
    major, minor, _ = ellipse_axes(cov)
    figures = {"east": state["east"], "north": state["north"], "ellipse95_m": [major, minor],
               "lat": state.get("lat"), "lon": state.get("lon"), "cov": state["cov"]}
    if major > max_ellipse:
        return False, f"95 % ellipse {major:.1f} m is wider than --max-ellipse {max_ellipse:g} m", figures
    if "truth" in state:
        err = np.array([state["east"] - state["truth"][0], state["north"] - state["truth"][1]])
        figures["error_m"] = float(np.hypot(*err))
        figures["nees"] = nees = crlb_nees(err, cov)
        if nees > CONVERGE_SCALE**2 * ELLIPSE_95:
            return False, f"the truth is {figures['error_m']:.1f} m off, outside {CONVERGE_SCALE:g}x the 95 % ellipse", figures
    return True, "converged", figures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m aoa_localizer.launch", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", choices=sorted(SCENARIOS), default="seed")
    parser.add_argument("--speedup", type=float, default=10.0, help="simulated seconds per wall second (default 10)")
    parser.add_argument("--duration", type=float, help="simulated seconds to play (default: the whole scenario)")
    parser.add_argument("--data-seed", type=int, default=0, help="seed of the simulated data")
    parser.add_argument("--bag", type=Path, help="replay this bag into the node instead of the simulated vehicle")
    parser.add_argument("--rate", type=float, default=10.0, help="with --bag: replay rate (0: as fast as allowed)")
    parser.add_argument("--record", type=Path, help="record every topic into this rosbag2 MCAP bag directory")
    parser.add_argument("--seed", type=int, help="the node's filter seed")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE", help="node parameter")
    parser.add_argument("--params-file", type=Path, help="node parameters file (ROS 2 YAML)")
    parser.add_argument("--vehicle-param", action="append", default=[], metavar="NAME=VALUE",
                        help="sim_vehicle parameter, e.g. gps_dropout_prob=0.1")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: random in 1-101, the range ROS recommends)")
    parser.add_argument("--timeout", type=float, default=600.0, help="wall seconds before giving up")
    parser.add_argument("--max-ellipse", type=float, default=50.0, help="widest 95 %% ellipse (m) called converged")
    parser.add_argument("--result", type=Path, help="write the final estimate and verdict as JSON")
    args = parser.parse_args(argv)
    if args.record and args.record.exists():
        print(f"launch: {args.record} exists; choose a new directory", file=sys.stderr)
        return 2
    if args.bag and not args.bag.exists():
        print(f"launch: no bag at {args.bag}", file=sys.stderr)
        return 2

    domain = args.domain_id if args.domain_id is not None else random.Random(os.getpid() ^ time.time_ns()).randint(1, 101)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    node_cmd, source_cmd = build_commands(args, node_parameters(args))
    logdir = Path(tempfile.mkdtemp(prefix="aoa_launch_"))
    source_name = "replay" if args.bag else "sim_vehicle"
    print(f"ROS_DOMAIN_ID={domain}; logs in {logdir}; {source_name}: "
          f"{args.bag if args.bag else f'scenario {args.scenario} at {args.speedup:g}x'}", flush=True)

    stop = _StopOnce()
    old = {s: signal.signal(s, stop) for s in (signal.SIGTERM, signal.SIGINT)}
    children, monitor, code = [], None, 2
    try:
        monitor = Monitor(args.record)
        node = Child("aoa_localizer", node_cmd, env, logdir)
        children.append(node)
        monitor.spin(1.5)  # let the node come up and the monitor discover it
        if not node.running():
            print(f"launch: the localizer exited at start (code {node.proc.returncode}):\n{node.tail()}", file=sys.stderr)
            return 2
        source = Child(source_name, source_cmd, env, logdir)
        children.append(source)
        t0, next_print = time.monotonic(), 0.0
        while source.running():
            monitor.spin(0.2)
            if not node.running():
                print(f"launch: the localizer died (code {node.proc.returncode}):\n{node.tail()}", file=sys.stderr)
                return 2
            elapsed = time.monotonic() - t0
            if elapsed > args.timeout:
                print(f"launch: timeout after {args.timeout:g} s", file=sys.stderr)
                return 2
            if elapsed >= next_print:
                print(progress_line(monitor.state(), elapsed), flush=True)
                next_print += 2.0
        if source.proc.returncode != 0:
            print(f"launch: {source_name} failed (code {source.proc.returncode}):\n{source.tail()}", file=sys.stderr)
            return 2
        monitor.spin(1.5)  # the last observation point closes on the last fixes
        ok, why, figures = verdict(monitor.state(), args.max_ellipse)
        print_result(ok, why, figures)
        if args.result:
            args.result.write_text(json.dumps({"converged": ok, "reason": why, **figures}, indent=1))
        code = 0 if ok else 1
    except Stop as exc:
        print(f"launch: stopped by {exc}", file=sys.stderr)
        code = 2
    finally:
        stop.stopping = True  # a Ctrl-C during the cleanup must not cut it short with a traceback
        for child in reversed(children):
            child.stop()
        if monitor is not None:
            if monitor.recorder:
                print(f"recorded {monitor.recorder.count} messages into {args.record}")
            monitor.close()
        for s, handler in old.items():
            signal.signal(s, handler)
    return code


def progress_line(state: dict, elapsed: float) -> str:
    d = state.get("diag", {})
    line = f"[{elapsed:5.1f} s] {d.get('status', 'waiting for the localizer')}; " \
           f"bearings received {d.get('bearings_received', 0)}, used {d.get('bearings_used', 0)}"
    if "east" in state:
        line += f"; estimate E {state['east']:.1f} N {state['north']:.1f}"
        if "truth" in state:
            line += f", error {math.hypot(state['east'] - state['truth'][0], state['north'] - state['truth'][1]):.1f} m"
    return line


def print_result(ok: bool, why: str, f: dict):
    if f:
        where = f"lat {f['lat']:.7f} lon {f['lon']:.7f}, " if f.get("lat") is not None else ""
        print(f"estimate: {where}E {f['east']:.1f} m N {f['north']:.1f} m, "
              f"95% ellipse {f['ellipse95_m'][0]:.1f} m x {f['ellipse95_m'][1]:.1f} m")
        if "error_m" in f:
            print(f"error against the simulated truth: {f['error_m']:.2f} m")
    print(f"result: {why}")


if __name__ == "__main__":
    sys.exit(main())
