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
import functools
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from aoa_localizer.common.cli import HelpFormatter, finite_number, integer_in, seed_value
from aoa_localizer.common.output import check_folder
from aoa_localizer.core.spec import ConfigError, unknown_names
from aoa_localizer.engine.config import parameter_specs
from aoa_localizer.engine.crlb import ELLIPSE_95, ellipse_axes
from aoa_localizer.engine.crlb import nees as crlb_nees
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.scheduling.memory import settle_process
from aoa_localizer.engine.scheduling.parent_death import die_with_parent
from aoa_localizer.engine.types import EstimateState
from aoa_localizer.ros.node_params import NODE_PARAMS
from aoa_localizer.ros.sim_vehicle import VEHICLE_SPECS
from aoa_localizer.simulation.fleet import FLEETS
from aoa_localizer.simulation.scenarios import SCENARIOS, moving_cells, receiver_settings
from msgs_adapters.bag import TOPICS, BagError, RawReader, found_stations
from msgs_adapters.bag_files import BagFiles, BagFilesError

CONVERGE_SCALE = 3.0  # the truth must lie inside the 95 % ellipse scaled by this
DIAG_LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}  # diagnostic_msgs/DiagnosticStatus levels
# After the source ends the node is judged once its counts stand still over two /diagnostics, or after this long
SETTLED_COUNTS = ("fixes_received", "bearings_received", "bearings_used", "points_used")
SETTLE_MAX_S = 30.0
# A domain is another graph's when someone publishes on a topic ending so; the launcher picks this many at most
RUN_TOPICS = ("gps/fix", "df/bearing", "sim/truth", "emitter/pose")
DOMAIN_TRIES = 5
CROWDED_LINES = 3  # times the launcher says who else publishes on the node's inputs, as discovery names them
_UNNAMED = "_NODE_NAME_UNKNOWN_"  # rmw's name for a node whose endpoints came before its name


class Stop(Exception):
    """SIGTERM or SIGINT to the launcher."""


class _StopOnce:
    """Signal handler: the first SIGINT or SIGTERM raises Stop; later ones (a second Ctrl-C while the children
    are being stopped) only say so, so the cleanup finishes instead of ending in a traceback.

    An exception raised from a handler lands wherever the main thread is, and some places swallow it (logging's
    after-fork hook while a child starts: the launcher then ran on to its timeout), so the loops also ask
    `check()`, which raises the signal's Stop once it was missed."""

    def __init__(self):
        self.stopping = self.signalled = False
        self.name = ""
        self.handled = False  # main() caught the Stop

    def __call__(self, signum, frame):
        if self.stopping:
            print("launch: already stopping; the children get a few seconds to exit", file=sys.stderr)
            return
        self.stopping = self.signalled = True
        self.name = signal.Signals(signum).name
        self.check()

    def check(self) -> None:
        """Raise the signal's Stop if a signal came and main() has not caught its Stop yet."""
        if self.signalled and not self.handled:
            raise Stop(self.name)


def ros_value(v) -> str:
    """A Python value as a --ros-args -p value (YAML)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, list):
        return "[" + ",".join(ros_value(x) for x in v) + "]"
    return str(v)


def parse_params(items, option: str = "-p") -> dict:
    """NAME=VALUE items (or ROS 2's NAME:=VALUE) as a dict; ValueError naming the option for one without '='."""
    out = {}
    for item in items:
        name, sep, value = item.partition(":=") if ":=" in item else item.partition("=")
        if not sep:
            raise ValueError(f"{option} takes NAME=VALUE, got {item!r}")
        out[name.strip()] = value.strip()
    return out


class Child:
    """A child process in its own session, its output in a log file."""

    def __init__(self, name: str, cmd: list[str], env: dict, logdir: Path):
        self.name = name
        self.log_path = logdir / f"{name}.log"
        self.log = open(self.log_path, "w")
        self.proc = subprocess.Popen(cmd, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True,
                                     preexec_fn=die_with_parent)

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


def stations_of_bag(args) -> dict[str, dict[str, str]]:
    """With --bag of several stations and no --scenario that names them: the stations its topic names show (the
    node then gets `stations`, the replay their topics), said in a warning; {} otherwise or for an unreadable bag
    (replay says why)."""
    if not args.bag or args.scenario in FLEETS:
        return {}
    try:
        with BagFiles(args.bag) as files:
            return found_stations(args.bag, RawReader(files).topics(), TOPICS) or {}
    except (BagFilesError, BagError):
        return {}


def bag_inputs(args, found: dict[str, dict[str, str]]) -> dict[str, list[str]]:
    """The bag's topics the replay plays into the node, by kind ("fix", "bearing")."""
    if args.scenario in FLEETS:
        names = FLEETS[args.scenario].stations
        return {"fix": [f"/{name}/gps/fix" for name in names], "bearing": [f"/{name}/df/bearing" for name in names]}
    if found:
        return {kind: [its[kind] for its in found.values()] for kind in ("fix", "bearing")}
    return {"fix": ["/gps/fix"], "bearing": ["/df/bearing"]}


def inputs_lost(args, found: dict[str, dict[str, str]], diag: dict) -> str | None:
    """After a whole replay: what the bag holds of the node's inputs that the node never took (lost in its input
    queue or before its subscription matched), in words; None when it took them all."""
    try:
        with BagFiles(args.bag) as files:
            counts = {t.name: t.count for t in RawReader(files).topics()}
    except (BagFilesError, BagError):
        return None
    short = []
    for kind, topics in bag_inputs(args, found).items():
        plural = {"fix": "fixes", "bearing": "bearings"}[kind]
        sent, took = sum(counts.get(t, 0) for t in topics), int(diag.get(f"{plural}_received", 0))
        if took < sent:
            short.append(f"{took} of {sent} {plural}")
    return None if not short else (f"the node took {' and '.join(short)} the replay sent; the rest were lost before "
                                   "it took them (its input queue, or its subscription matched late): replay at a "
                                   "lower --rate")


def build_commands(args, node_params: dict, found: dict[str, dict[str, str]]) -> tuple[list[str], list[str]]:
    """The node's and the source's command lines; `found`: the bag's stations (stations_of_bag)."""
    py = sys.executable
    node = [py, "-m", "aoa_localizer.node", "--ros-args"]
    if args.params_file:
        node += ["--params-file", str(args.params_file)]
    for k, v in node_params.items():
        node += ["-p", f"{k}:={ros_value(v)}"]
    if args.bag:
        inputs = [topic for topics in bag_inputs(args, found).values() for topic in topics]
        # every played topic has a subscriber here (the node's inputs, the monitor's truth and datum)
        source = [py, "-m", "aoa_localizer.replay", str(args.bag), "--rate", str(args.rate), "--wait", "30",
                  "--topics", *inputs, "/sim/truth", "/sim/datum"]
    else:
        source = [py, "-m", "aoa_localizer.sim_vehicle", "--ros-args", "-p", f"scenario:={args.scenario}",
                  "-p", f"speedup:={float(args.speedup)}", "-p", f"data_seed:={args.data_seed}",
                  "-p", f"wait_for_subscribers:={2 if args.record else 1}"]
        if args.duration:
            source += ["-p", f"duration_s:={float(args.duration)}"]
        for k, v in parse_params(args.vehicle_param, "--vehicle-param").items():
            source += ["-p", f"{k}:={ros_value(vehicle_value(v))}"]
    return node, source


def vehicle_value(text: str):
    """--vehicle-param's TEXT as ROS reads it (YAML), with numbers YAML 1.1 takes for text (`433.92e6`) read as the
    numbers they are, as `simulate --emitters` reads them: one reading of numbers everywhere."""
    def number(v):
        if isinstance(v, list):  # ROS takes no mixed lists: a list of numbers is of floats
            items = [number(x) for x in v]
            numeric = all(isinstance(x, int | float) and not isinstance(x, bool) for x in items)
            return [float(x) for x in items] if numeric else items
        if isinstance(v, str):
            try:
                x = float(v)
            except ValueError:
                return v
            return x if math.isfinite(x) else v
        return v

    return number(yaml.safe_load(text))


def node_parameters(args, found: dict[str, dict[str, str]] | None = None) -> dict:
    """The scenario's frame and filter settings (so the node's map is the truth's), the bag's stations (`found`,
    read from the bag when not given), then the user's -p."""
    if found is None:
        found = stations_of_bag(args)
    # The launcher's own sources (its vehicle, a bag it plays) are read reliably: on a machine too busy for the pace
    # they are played at, a best-effort read lost half the bearings before the first estimate (a receiver's own
    # stream stays best effort, the node's default; -p input_reliability wins)
    params: dict = {"input_reliability": "reliable", "input_queue_depth": 2000}  # the sources' own history's depth
    if args.scenario:
        fleet = FLEETS.get(args.scenario)
        sc = fleet.first if fleet else {**SCENARIOS, **moving_cells()}[args.scenario]
        if not args.bag:
            params.update(datum_lat=sc.datum[0], datum_lon=sc.datum[1], datum_alt=sc.datum[2])
        params.update(sc.filter_overrides)
        if fleet:
            params.update(fleet.node_params())
    if found:
        params["stations"] = list(found)
    if args.seed is not None:
        params["seed"] = args.seed
    # The node must read what the vehicle publishes: its bearing encoding and its array's mounting go to the node too.
    vehicle = parse_params(args.vehicle_param, "--vehicle-param")
    if vehicle.get("bearing_encoding") in ("df_record", "pose"):  # scans come on df/scan, whatever df/bearing's
        params["bearing_encoding"] = vehicle["bearing_encoding"]
    if vehicle.get("mount_offset_deg"):
        params.update(receiver_settings(float(yaml.safe_load(vehicle["mount_offset_deg"]))))
    params.update(parse_params(args.param))
    return params


class Monitor:
    """The launcher's own node: follows emitter/pose, sim/truth, /diagnostics; records if asked."""

    def __init__(self, record: Path | None, co_channel: list[tuple[float, float]] | None = None,
                 check_signal: Callable[[], None] = lambda: None):
        """`co_channel`: the vehicle's other transmitters on the emitter's frequency (east, north in the simulation's
        map, as sim/truth's), each a truth the channel's estimate and transmitters may be nearest; `check_signal`
        raises once the launcher was told to stop (asked between spins)."""
        self.check_signal = check_signal
        import rclpy
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        from msgs_adapters.build import rclpy_types

        rclpy.init(args=[], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.rclpy = rclpy
        self.node = rclpy.create_node("aoa_launch")
        T = rclpy_types()
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pose = self.truth = self.diag = None
        self.co_channel = list(co_channel or [])
        self.node.create_subscription(
            T.PoseWithCovarianceStamped, "emitter/pose", lambda m: setattr(self, "pose", m), latched
        )
        self.node.create_subscription(T.PointStamped, "sim/truth", lambda m: setattr(self, "truth", m), latched)
        self.sim_datum = self.node_datum = None  # the truth's map origin, and the node's (they differ with --bag)
        self.node.create_subscription(T.NavSatFix, "sim/datum", lambda m: setattr(self, "sim_datum", m), latched)
        self.node.create_subscription(T.NavSatFix, "emitter/datum", lambda m: setattr(self, "node_datum", m),
                                      latched)
        self.node.create_subscription(T.NavSatFix, "emitter/fix", lambda m: setattr(self, "fix", m), 10)
        self.node.create_subscription(T.DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        # every channel's pose and, from a simulation with several transmitters, its own truth (emitter/channels
        # names them as they open)
        self.T, self.latched = T, latched
        self.channel_poses: dict[str, Any] = {}
        self.channel_truths: dict[str, Any] = {}
        self.truths_followed: set[str] = set()  # channels whose sim/CHANNEL/truth is subscribed
        self.truths_looked = 0.0  # when the graph was last looked at for them (monotonic s)
        self.summary: dict[str, dict] = {}  # the latest emitter/channels: each channel's entry
        self.transmitter_poses: dict[str, Any] = {}  # topic: the latest pose of a co-channel transmitter
        self.node.create_subscription(T.String, "emitter/channels", self._on_channels, latched)
        self.diagnostics_seen = 0
        # the worst level the node's own status reached during the run, and what it said then (a good run stays OK)
        self.worst_diag: tuple[int, str] = (0, "")
        self.crowded = ""  # the node's input_publishers warning, as last said: another source on its inputs
        self.crowded_said = 0  # how many times (a source first seen unnamed is said again once discovery names it)
        self.fix = None
        self.recorder = None
        if record is not None:
            from msgs_adapters.recorder import BagRecorder

            self.recorder = BagRecorder(self.node, record)

    def spin(self, seconds: float):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.check_signal()
            self.rclpy.spin_once(self.node, timeout_sec=min(0.05, max(0.0, end - time.monotonic())))
            if self.recorder:
                self.recorder.poll()
            if time.monotonic() >= self.truths_looked + 0.5:
                self._follow_truths()

    def _follow_truths(self) -> None:
        """Each transmitter's truth (sim/CHANNEL/truth) taken as soon as the vehicle offers it: the vehicle's
        latched truths leave with it, and a subscription made once the node named the channel came too late on a
        busy machine (a channel's line then had no error against its truth)."""
        self.truths_looked = time.monotonic()
        for name, _ in self.node.get_topic_names_and_types():
            parts = name.strip("/").split("/")
            if len(parts) == 3 and parts[0] == "sim" and parts[2] == "truth":
                self._truth_of(parts[1])

    def _truth_of(self, channel: str) -> None:
        if channel not in self.truths_followed:
            self.truths_followed.add(channel)
            self.node.create_subscription(self.T.PointStamped, f"sim/{channel}/truth",
                                          functools.partial(self.channel_truths.__setitem__, channel), self.latched)

    def _on_channels(self, msg) -> None:
        self.summary = json.loads(msg.data).get("channels", {})
        for entry in self.summary.values():
            for k in range(1, len(entry.get("transmitters", [])) + 1):
                topic = f"{entry['topics']}transmitter_{k}/pose"
                if topic not in self.transmitter_poses:
                    self.transmitter_poses[topic] = None
                    self.node.create_subscription(self.T.PoseWithCovarianceStamped, topic,
                                                  functools.partial(self.transmitter_poses.__setitem__, topic),
                                                  self.latched)
        for channel in self.summary:
            if channel in self.channel_poses or channel == "default":
                continue
            self.channel_poses[channel] = None
            self.node.create_subscription(self.T.PoseWithCovarianceStamped, f"emitter/{channel}/pose",
                                          functools.partial(self.channel_poses.__setitem__, channel), self.latched)
            self._truth_of(channel)

    def channel_lines(self) -> list[str]:
        """One line per frequency channel: its estimate, and its error against its own truth when the simulation
        gave one (in the node's map frame, as the verdict's)."""
        from msgs_adapters.fields import estimate_from_pose

        lines = []
        for channel, pose in sorted(self.channel_poses.items()):
            if pose is None:
                lines.append(f"channel {channel}: no estimate")
                continue
            _, east, north, cov = estimate_from_pose(pose)
            major, minor, _ = ellipse_axes(np.array(cov))
            line = f"channel {channel}: E {east:.1f} m N {north:.1f} m, 95% ellipse {major:.1f} m x {minor:.1f} m"
            truth = self._in_node_frame(self.channel_truths.get(channel))
            if truth is not None:
                err = np.array([east - truth[0], north - truth[1]])
                inside = "inside" if crlb_nees(err, np.array(cov)) <= ELLIPSE_95 else "outside"
                line += f"; error against its truth {float(np.hypot(*err)):.2f} m ({inside} its ellipse)"
            lines.append(line)
        truths = [t for t in [self.truth_in_node_frame(), *self.co_channel_truths()] if t is not None]
        for channel, entry in sorted(self.summary.items()):
            if entry.get("transmitter_count", 1) >= 2:
                # the default channel's transmitters against the vehicle's transmitters on its frequency
                near = truths if channel == "default" and len(truths) > 1 else []
                places = "; ".join(f"transmitter_{j}: E {t['east']:.1f} N {t['north']:.1f} ({100 * t['share']:.0f} %, "
                                   f"{t['state']}"
                                   + (f", {_nearest(t['east'], t['north'], near)[1]:.1f} m from the nearest truth"
                                      if near else "") + ")"
                                   for j, t in enumerate(entry["transmitters"], start=1))
                lines.append(f"channel {channel}: {entry['transmitter_count']} transmitters on its frequency "
                             f"(p = {entry['count_probability']:.2f}): {places}")
        return lines

    def _on_diagnostics(self, msg) -> None:
        from msgs_adapters.fields import diagnostics_values

        self.diag, self.diagnostics_seen = msg, self.diagnostics_seen + 1
        own = diagnostics_values(msg).get("aoa_localizer: localizer", {})
        # the run's diagnostics count from the node's first input: before it, "no DF reading since the start" is
        # the source still starting (a simulated drive computed, a replay loading its bag)
        fed = any(own.get(k, "0") != "0" for k in ("fixes_received", "bearings_received"))
        if fed and "level" in own and int(own["level"]) > self.worst_diag[0]:
            self.worst_diag = (int(own["level"]), own.get("message", ""))
        crowded = own.get("input_publishers")
        # another graph that discovery had not shown when the domain was chosen; said again as its names arrive
        if crowded and crowded != self.crowded and self.crowded_said < CROWDED_LINES:
            self.crowded, self.crowded_said = crowded, self.crowded_said + 1
            print(f"launch: another source publishes on the node's inputs: {crowded}", file=sys.stderr, flush=True)

    def settle(self, at_least_s: float, at_most_s: float) -> bool:
        """Spin until the node has worked through what it received: two /diagnostics in a row with the same counts
        (fixes and bearings received and used) and the same newest estimate, no search or check of its own still
        under way (`jobs_running`: a search, check, count or site-part fit), after `at_least_s`; False when
        `at_most_s` passed first (a busy machine's node still working, or a node that says nothing)."""
        start = time.monotonic()
        seen, last, same = self.diagnostics_seen, None, 0
        while time.monotonic() - start < at_most_s:
            self.spin(0.2)
            if self.diagnostics_seen == seen:
                continue
            seen = self.diagnostics_seen
            state = self.state()
            now = (tuple(state.get("diag", {}).get(k) for k in SETTLED_COUNTS), state.get("stamp"),
                   state.get("east"))
            same, last = (same + 1 if now == last else 0), now
            # a start search or check still under way (a busy machine's worker) is work the verdict must wait for
            working = state.get("diag", {}).get("jobs_running", "0") != "0"
            if same >= 1 and not working and time.monotonic() - start >= at_least_s:
                return True
        return False

    def state(self) -> dict:
        from msgs_adapters.fields import diagnostics_values, estimate_from_pose

        out: dict = {}
        if self.diag is not None:
            out["diag"] = diagnostics_values(self.diag).get("aoa_localizer: localizer", {})
        if self.pose is not None:
            stamp, east, north, cov = estimate_from_pose(self.pose)
            out.update(stamp=stamp, east=east, north=north, cov=cov)
        if self.fix is not None:
            out.update(lat=self.fix.latitude, lon=self.fix.longitude)
        truth = self.truth_in_node_frame()
        if truth is not None:
            out["truth"] = truth
            out["truths"] = [truth, *self.co_channel_truths()]
        if self.node_datum is not None:  # what east and north are measured from
            out["datum"] = (self.node_datum.latitude, self.node_datum.longitude)
        return out

    def truth_in_node_frame(self) -> tuple[float, float] | None:
        """sim/truth (east, north in the simulation's map at sim/datum) in the node's map at emitter/datum, so
        the error is measured in one frame; None until the truth and both datums are known."""
        return self._in_node_frame(self.truth)

    def co_channel_truths(self) -> list[tuple[float, float]]:
        """The vehicle's other transmitters on the emitter's frequency in the node's map ([] until both datums are
        known, or without them)."""
        return [t for t in (self._enu_in_node_frame(e, n) for e, n in self.co_channel) if t is not None]

    def _in_node_frame(self, truth) -> tuple[float, float] | None:
        return None if truth is None else self._enu_in_node_frame(truth.point.x, truth.point.y)

    def _enu_in_node_frame(self, east: float, north: float) -> tuple[float, float] | None:
        if self.sim_datum is None or self.node_datum is None:
            return None
        sim = LocalFrame(self.sim_datum.latitude, self.sim_datum.longitude, self.sim_datum.altitude)
        lat, lon, _ = sim.to_geodetic(east, north)
        node = LocalFrame(self.node_datum.latitude, self.node_datum.longitude, self.node_datum.altitude)
        east, north = node.to_enu(lat, lon, self.node_datum.altitude)
        return float(east), float(north)

    def close(self, exit_code: int):
        """Close the recording, then the launcher's node and rclpy (within ros_main.TEARDOWN_S, else the process
        exits with `exit_code`: the verdict is said by then)."""
        from aoa_localizer.ros.ros_main import bounded_teardown

        if self.recorder:
            self.recorder.close()

        def teardown():
            try:
                self.node.destroy_node()
            finally:
                self.rclpy.try_shutdown()

        bounded_teardown("launch", teardown, exit_code)


def _nearest(east: float, north: float, truths: list) -> tuple[int, float]:
    """The index of the truth nearest (east, north), and its distance (m)."""
    dist = [float(np.hypot(east - t[0], north - t[1])) for t in truths]
    k = int(np.argmin(dist))
    return k, dist[k]


def verdict(state: dict, max_ellipse: float) -> tuple[bool, str, dict]:
    """Converged or not, why, and the figures."""
    if "east" not in state:
        status = state.get("diag", {}).get("status", "no diagnostics received")
        return False, f"no estimate was published ({status})", {}
    cov = np.array(state["cov"])
    major, minor, _ = ellipse_axes(cov)
    figures = {
        "east": state["east"],
        "north": state["north"],
        "ellipse95_m": [major, minor],
        "lat": state.get("lat"),
        "lon": state.get("lon"),
        "cov": state["cov"],
        "datum": state.get("datum"),
    }
    diag = state.get("diag", {})
    if diag.get("state"):
        figures["state"] = diag["state"]
    if diag.get("state") == EstimateState.SUSPECT:  # the localizer says its model does not fit: never "converged"
        said = "; ".join(v for k, v in sorted(diag.items()) if k.startswith("warning_"))
        return False, f"the localizer calls its estimate suspect: {said or diag.get('message', '')}", figures
    if major > max_ellipse:
        return False, f"95 % ellipse {major:.1f} m is wider than --max-ellipse {max_ellipse:g} m", figures
    if "truth" in state:
        # several transmitters on the frequency (co_channel): the estimate follows one of them, the nearest
        k, _ = _nearest(state["east"], state["north"], state.get("truths") or [state["truth"]])
        truth = (state.get("truths") or [state["truth"]])[k]
        if k:
            figures["co_channel_truth"] = [float(truth[0]), float(truth[1])]
        err = np.array([state["east"] - truth[0], state["north"] - truth[1]])
        figures["error_m"] = float(np.hypot(*err))
        figures["nees"] = nees = crlb_nees(err, cov)
        if nees > CONVERGE_SCALE**2 * ELLIPSE_95:
            return (
                False,
                f"the truth is {figures['error_m']:.1f} m off, outside {CONVERGE_SCALE:g}x the 95 % ellipse",
                figures,
            )
    return True, "converged", figures


def parse_args(argv) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m aoa_localizer.launch", description=__doc__,
                                     formatter_class=HelpFormatter)
    parser.add_argument("--scenario", choices=sorted(SCENARIOS) + sorted(FLEETS) + sorted(moving_cells()),
                        help="public scenario to simulate (docs/benchmarks.md, Scenarios; unset: seed); with --bag, "
                        "the scenario whose receiver settings the node gets (unset: the node's defaults)")
    parser.add_argument("--speedup", type=finite_number(0.0), default=10.0, metavar="X",
                        help="simulated seconds per wall second (0: as fast as the vehicle's max_rate_hz)")
    parser.add_argument("--duration", type=finite_number(0.0, low_open=True), metavar="S",
                        help="simulated seconds to play (unset: the whole scenario)")
    parser.add_argument("--data-seed", type=seed_value, default=0, metavar="N", help="seed of the simulated data")
    parser.add_argument("--bag", type=Path, metavar="DIR",
                        help="replay this bag into the node instead of the simulated vehicle")
    parser.add_argument("--rate", type=finite_number(0.0), default=10.0, metavar="X",
                        help="with --bag: replay rate (0: as fast as allowed)")
    parser.add_argument("--record", type=Path, metavar="DIR",
                        help="record every topic into this rosbag2 MCAP bag directory")
    parser.add_argument("--seed", type=seed_value, metavar="N", help="the node's filter seed (unset: random)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE", help="node parameter")
    parser.add_argument("--params-file", type=Path, metavar="YAML", help="node parameters file (ROS 2 YAML)")
    parser.add_argument("--vehicle-param", action="append", default=[], metavar="NAME=VALUE",
                        help="sim_vehicle parameter, e.g. gps_dropout_prob=0.1")
    parser.add_argument("--domain-id", type=integer_in(0, 232), metavar="ID",
                        help="ROS_DOMAIN_ID, 0-232 (unset: random in 1-101, the range ROS recommends)")
    parser.add_argument("--timeout", type=finite_number(0.0, low_open=True), default=600.0, metavar="S",
                        help="wall seconds before giving up")
    parser.add_argument("--max-ellipse", type=finite_number(0.0, low_open=True), default=50.0, metavar="M",
                        help="widest 95 %% ellipse (m) called converged")
    parser.add_argument("--result", type=Path, metavar="FILE",
                        help="write the final estimate, the verdict and every channel (emitter/channels) as JSON")
    parser.add_argument("--keep-logs", action="store_true",
                        help="keep the processes' logs after a converged run too (a run that did not converge, or "
                             "was stopped, always keeps them)")
    args = parser.parse_args(argv)
    if args.scenario is None and not args.bag:
        args.scenario = "seed"
    return args


def _vehicle_value_problem(name: str, text: str) -> str | None:
    """Why --vehicle-param NAME=TEXT is refused (None: it is fine), read as ROS reads `-p NAME:=TEXT` (YAML)."""
    try:
        value = vehicle_value(text)
        VEHICLE_SPECS[name].spec.check(name, value)
    except (yaml.YAMLError, ConfigError) as exc:
        return f"--vehicle-param {exc}"
    return None


def refusal(args) -> str | None:
    """Why the options cannot run, before anything starts (None: they can)."""
    if args.record:
        try:
            check_folder(args.record, "--record", new=True)
        except ValueError as exc:
            return str(exc)
    if args.bag and not args.bag.exists():
        return f"no bag at {args.bag}"
    if args.params_file and not args.params_file.is_file():
        return f"no params file at {args.params_file}"
    try:
        node_names, vehicle_names = parse_params(args.param), parse_params(args.vehicle_param, "--vehicle-param")
    except ValueError as exc:
        return str(exc)
    known = [p.name for p in parameter_specs() + NODE_PARAMS]
    unknown = [n for n in node_names if n not in known]
    if unknown:
        return f"-p {unknown_names(unknown, known)}"
    unknown = [n for n in vehicle_names if n not in VEHICLE_SPECS]
    if unknown:
        return f"--vehicle-param {unknown_names(unknown, list(VEHICLE_SPECS))}"
    for name, text in vehicle_names.items():
        problem = _vehicle_value_problem(name, text)
        if problem:
            return problem
    encoding = vehicle_names.get("bearing_encoding")
    if encoding in ("df_record", "pose") and node_names.get("bearing_encoding", encoding) != encoding:
        return (f"the vehicle publishes bearing_encoding {encoding} but -p gives the node "
                f"{node_names['bearing_encoding']}: the node would receive nothing")
    if args.bag and (args.vehicle_param or args.duration or args.data_seed):
        return "--vehicle-param, --duration and --data-seed are for the simulated vehicle, not --bag"
    return None


def enter_domain(args) -> tuple[int | None, str]:
    """The run's own ROS domain (never 0 unless asked), set for this process and its children, and what was said of
    it. A domain the launcher picks must have no publisher on the run's topics (another graph there would mix its
    messages into the run: it picks again); a domain the user gave that has them is refused (None, and why)."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if args.domain_id is not None:
        others = foreign_publishers(args.domain_id)
        if others:
            return None, (f"ROS_DOMAIN_ID {args.domain_id} already has publishers on this run's topics ({others}): "
                          "their messages would mix with the run's; choose another --domain-id, or leave it out to "
                          "get a free one")
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
        return args.domain_id, ""
    pick = random.Random(os.getpid() ^ time.time_ns())
    said: list[str] = []
    for _ in range(DOMAIN_TRIES):
        domain = pick.randint(1, 101)
        others = foreign_publishers(domain)
        if not others:
            os.environ["ROS_DOMAIN_ID"] = str(domain)
            return domain, "; ".join(said)
        said.append(f"ROS_DOMAIN_ID {domain} is in use ({others}): picked another")
    return None, "; ".join(said) + f"; no free domain in {DOMAIN_TRIES} tries: give one with --domain-id"


def foreign_publishers(domain: int, wait_s: float = 1.5) -> str:
    """Who publishes on a run's topics (a GPS fix, a DF bearing, the simulation's truth, the node's pose) in
    `domain`, as "node on topic, ..." ("" when nobody does within `wait_s` of discovery)."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(args=[], context=ctx, domain_id=domain, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node("aoa_launch_probe", context=ctx)
        found: list[str] = []
        start = time.monotonic()
        # an endpoint is often discovered before its node's name: wait a little longer for the name
        while time.monotonic() - start < (2.0 * wait_s if found else wait_s):
            time.sleep(0.1)
            found = [f"{i.node_name} on {topic}" for topic, _ in node.get_topic_names_and_types()
                     if topic.endswith(RUN_TOPICS) for i in node.get_publishers_info_by_topic(topic)]
            if found and not any(_UNNAMED in f for f in found):
                break
        node.destroy_node()
        return ", ".join(sorted(set(found))[:5])
    finally:
        rclpy.try_shutdown(context=ctx)


class Run:
    """One launch: the node, the data source (vehicle or bag replay), the monitor; `close()` stops them all."""

    def __init__(self, args, logdir: Path, stop: _StopOnce):
        self.args, self.logdir, self.stop = args, logdir, stop
        self.env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.source_name = "replay" if args.bag else "sim_vehicle"
        self.children: list[Child] = []
        self.monitor: Monitor | None = None
        self.exit_code = 2  # the launcher's, once execute() gave its verdict (2: stopped or failed before one)

    def start(self, name: str, cmd: list[str]) -> Child:
        child = Child(name, cmd, self.env, self.logdir)
        self.children.append(child)
        return child

    def execute(self) -> int:
        """Start the node, then the source; watch until the source ends; print and return the verdict's code."""
        args = self.args
        found = stations_of_bag(args)
        node_cmd, source_cmd = build_commands(args, node_parameters(args, found), found)
        co = parse_params(args.vehicle_param, "--vehicle-param").get("co_channel")
        flat = [float(v) for v in vehicle_value(co)] if co else []
        self.monitor = monitor = Monitor(args.record, list(zip(flat[::2], flat[1::2], strict=False)),
                                                self.stop.check)
        node = self.start("aoa_localizer", node_cmd)
        # the source loads while the node does: it plays once the node's inputs have subscribers (sim_vehicle's
        # wait_for_subscribers, replay's --wait), then half a second more for the match to settle
        monitor.spin(1.5)
        if not node.running():
            print(f"launch: the localizer exited at start (code {node.proc.returncode}):\n{node.tail()}",
                  file=sys.stderr)
            return 2
        source = self.start(self.source_name, source_cmd)
        failure = self.watch(node, source)
        if failure:
            print(f"launch: {failure}", file=sys.stderr)
            return 2
        # the last observation point closes on the last fixes, and a busy node may still be working through its queue
        if not monitor.settle(1.5, SETTLE_MAX_S):
            print(f"launch: the node was still working {SETTLE_MAX_S:g} s after the source ended; judging what it "
                  "published", file=sys.stderr)
        state = monitor.state()
        lost = inputs_lost(args, found, state.get("diag", {})) if args.bag else None
        if lost:
            print(f"launch: {lost}", file=sys.stderr, flush=True)
        ok, why, figures = verdict(state, args.max_ellipse)
        if monitor.crowded:  # the estimate may rest on another graph's messages: never "converged"
            ok, why = False, (f"another source published on the node's inputs during the run ({monitor.crowded}); "
                              "run again in a free domain (leave out --domain-id)")
        print_result(ok, why, figures)
        level, said = monitor.worst_diag
        print("diagnostics: OK throughout" if level == 0 else
              f"diagnostics: reached {DIAG_LEVELS.get(level, level)} during the run ({said})")
        for line in monitor.channel_lines():  # the verdict is the primary channel's; every channel is reported
            print(line)
        if args.result:
            poses = {topic: None if pose is None else [pose.pose.pose.position.x, pose.pose.pose.position.y]
                     for topic, pose in monitor.transmitter_poses.items()}
            args.result.write_text(json.dumps({"converged": ok, "reason": why, **figures,
                                               "diagnostics_worst": {"level": level, "message": said},
                                               "channels": monitor.summary, "transmitter_poses": poses}, indent=1))
        return 0 if ok else 1

    def watch(self, node: Child, source: Child) -> str | None:
        """Spin the monitor and print progress every 2 s while the source runs; what went wrong, if anything."""
        assert self.monitor is not None
        t0, next_print = time.monotonic(), 0.0
        while source.running():
            self.monitor.spin(0.2)
            if not node.running():
                return f"the localizer died (code {node.proc.returncode}):\n{node.tail()}"
            elapsed = time.monotonic() - t0
            if elapsed > self.args.timeout:
                last = progress_line(self.monitor.state(), elapsed)
                return f"timeout after {self.args.timeout:g} s; last status {last}"
            if elapsed >= next_print:
                print(progress_line(self.monitor.state(), elapsed), flush=True)
                next_print += 2.0
        if source.proc.returncode != 0:
            return f"{self.source_name} failed (code {source.proc.returncode}):\n{source.tail()}"
        return None

    def close(self):
        """Stop the children and the monitor (once: a second call finds nothing left)."""
        for child in reversed(self.children):
            child.stop()
        self.children = []
        if self.monitor is not None:
            recorder = self.monitor.recorder
            self.monitor.close(self.exit_code)
            self.monitor = None
            if recorder and recorder.failed:
                print(f"recording stopped early ({recorder.failed}); {self.args.record} keeps what was written "
                      "before, and replay salvages it", flush=True)
            elif recorder:
                print(f"recorded {recorder.count} messages into {self.args.record}")


def main(argv=None) -> int:
    settle_process()  # it scores the node's estimates with numpy: BLAS on one thread (scheduling/memory.py)
    args = parse_args(argv)
    problem = refusal(args)
    if problem:
        print(f"launch: {problem}", file=sys.stderr)
        return 2
    stop = _StopOnce()
    old = {s: signal.signal(s, stop) for s in (signal.SIGTERM, signal.SIGINT)}
    run = None
    try:
        domain, said = enter_domain(args)
        if said:
            print(f"launch: {said}", file=sys.stderr, flush=True)
        if domain is None:
            return 2
        logdir = Path(tempfile.mkdtemp(prefix="aoa_launch_"))
        run = Run(args, logdir, stop)
        source = args.bag if args.bag else f"scenario {args.scenario} at {args.speedup:g}x"
        print(f"ROS_DOMAIN_ID={domain}; logs in {logdir}; {run.source_name}: {source}", flush=True)
        code = run.exit_code = run.execute()
        if code == 0 and not args.keep_logs:  # nothing to look into: no aoa_launch_* folder left behind
            run.close()
            shutil.rmtree(logdir, ignore_errors=True)
            print(f"logs removed (the run converged; --keep-logs keeps them in {logdir.parent})")
        return code
    except Stop as exc:
        stop.handled = True
        print(f"launch: stopped by {exc}", file=sys.stderr)
        return 2
    finally:
        stop.stopping = True  # a Ctrl-C during the cleanup must not cut it short with a traceback
        if run is not None:
            run.close()
        # Once stopped by a signal, the process is on its way out: a later one is ignored. Python's own exit puts a
        # handler it set back to the default (the process then ends by the signal: exit -2 where 2 was due), but
        # leaves an ignored signal ignored.
        for s, handler in old.items():
            signal.signal(s, signal.SIG_IGN if stop.signalled else handler)


def progress_line(state: dict, elapsed: float) -> str:
    d = state.get("diag", {})
    line = (
        f"[{elapsed:5.1f} s] {d.get('status', 'waiting for the localizer')}; "
        f"bearings received {d.get('bearings_received', 0)}, used {d.get('bearings_used', 0)}"
    )
    if d.get("overload"):  # the node could not keep up: what it lost is not the data's fault
        line += f"; OVERLOAD: {d['overload']}"
    if "east" in state:
        line += f"; estimate E {state['east']:.1f} N {state['north']:.1f}"
        if "truth" in state:
            line += f", error {math.hypot(state['east'] - state['truth'][0], state['north'] - state['truth'][1]):.1f} m"
    return line


def print_result(ok: bool, why: str, f: dict):
    if f:
        where = f"lat {f['lat']:.7f} lon {f['lon']:.7f}, " if f.get("lat") is not None else ""
        origin = f" from the node's datum {f['datum'][0]:.7f}, {f['datum'][1]:.7f}" if f.get("datum") else ""
        print(
            f"estimate: {where}E {f['east']:.1f} m N {f['north']:.1f} m{origin}, "
            f"95% ellipse semi-axes {f['ellipse95_m'][0]:.1f} m x {f['ellipse95_m'][1]:.1f} m"
        )
        if "error_m" in f:
            near = f.get("co_channel_truth")
            which = (f" (the nearest truth: the vehicle's co_channel transmitter at E {near[0]:.1f} N {near[1]:.1f}; "
                     "the channel's estimate follows one of the transmitters on its frequency)" if near else "")
            print(f"error against the simulated truth: {f['error_m']:.2f} m{which}")
        if "state" in f:
            print(f"state: {f['state']}")
    print(f"result: {why}")


if __name__ == "__main__":
    sys.exit(main())
