"""The localizer node (`aoa_localizer`): GPS fixes and DF bearings in, the emitter's position out.

    python -m aoa_localizer.node --ros-args -p algorithm:=afsa --params-file params.yaml -r df/bearing:=/df1/bearing

Inputs `gps/fix`, `df/bearing` (sensor-data QoS: reliable and best-effort publishers both connect), or
`NAME/gps/fix`, `NAME/df/bearing` per station of `stations`; outputs `emitter/pose` (latched), `emitter/fix`,
`emitter/particles`, `emitter/markers`, `emitter/posterior` (while listened to), `emitter/next_goal` and its marker,
the same under `emitter/<channel>/` per frequency channel (and `transmitter_<k>/pose` for each of several
transmitters sharing it), the latched summary `emitter/channels`, the latched
`emitter/datum`, `/diagnostics` at 1 Hz, and Cursor-on-Target to TAK with `cot_url`; services `~/reset` and
`~/reset_datum`. Every
LocalizerConfig field is a parameter (a filter's own settings as `<filter>.*`); a changed parameter restarts the
track with the new settings, an invalid one is refused with its reason.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from aoa_localizer.common.cot import CotSender, CotUnavailable, estimate_event
from aoa_localizer.core.spec import ConfigError, IncompleteGroup, ParameterSpec, unknown_names
from aoa_localizer.engine.config import LocalizerConfig, parameter_specs
from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.engine.outputs.view import LocalizerView
from aoa_localizer.engine.rejections import REASONS
from aoa_localizer.engine.scheduling.memory import OldObjects
from aoa_localizer.ros.declare import declare, refuse_unknown, value_of
from aoa_localizer.ros.fix_wait import FixWait
from aoa_localizer.ros.node_monitor import NodeMonitor
from aoa_localizer.ros.node_outputs import NodeOutputs, PosteriorWork
from aoa_localizer.ros.node_params import NODE_PARAMS, STATION_POSITION
from aoa_localizer.ros.ros_main import run_node, spin
from aoa_localizer.ros.vehicle_path import VehiclePath
from msgs_adapters import build
from msgs_adapters.fields import (
    df_record,
    df_scan,
    fix_from_navsatfix,
    heading_from_imu,
)

NODE_NAME = "aoa_localizer"
DATUM_PARAMS = frozenset({"datum_lat", "datum_lon", "datum_alt"})  # the only parameters that move the map frame
INPUT_TYPES = {"df_record": "geometry_msgs/msg/Vector3Stamped", "pose": "geometry_msgs/msg/PoseWithCovarianceStamped"}
FIX_TYPE = "sensor_msgs/msg/NavSatFix"
SCAN_TYPE = "sensor_msgs/msg/PointCloud2"
ENGINE_LOGGER = "aoa_localizer"  # the engine's logger (engine/localizer.py); its modules' are children
_UNNAMED = "_NODE_NAME_UNKNOWN_"  # rmw's name for a node whose endpoints were discovered before its name
DRAIN_MAX = 100  # DF records handled per executor callback beyond the first (then timers and services get a turn)
# The queued fixes are taken before every this many drained records: a record a take of the fix queue cost the node
# 12 % more CPU at 5000 records/s, and 10 records are at most a second of one channel's stream at 10 Hz
FIRST_EVERY = 10

_NODE_SPECS = {p.name: p for p in NODE_PARAMS}
ENGINE_SPECS = parameter_specs()
ENGINE_PARAMS = frozenset(p.name for p in ENGINE_SPECS)


class RosLogHandler(logging.Handler):
    """Python logging records (the engine's: datum set, filter started, re-starts) forwarded to a ROS logger, so
    they reach the console and /rosout like the node's own lines."""

    def __init__(self, ros_logger):
        super().__init__()
        self.ros_logger = ros_logger

    def emit(self, record: logging.LogRecord):
        # One call line per severity: rclpy keys its log settings on the calling line and raises "Logger severity
        # cannot be changed between calls" when one line logs at two severities (it crashed the node's callback).
        # The engine's own logger carries the node's name already ("[aoa_localizer]: ..."); a module's adds its own.
        where = "" if record.name == ENGINE_LOGGER else f"{record.name}: "
        level, ros, text = record.levelno, self.ros_logger, where + record.getMessage()
        if level >= logging.ERROR:
            ros.error(text)
        elif level >= logging.WARNING:
            ros.warning(text)
        elif level >= logging.INFO:
            ros.info(text)
        else:
            ros.debug(text)


class Drain:
    """Handle the message the executor took, then up to DRAIN_MAX more already queued on `subscription`, the messages
    queued on `first` (the station's fixes, with their handler) before the first and every FIRST_EVERY-th of them: a
    DF stream drained ahead of the fixes queued beside it would leave its bearings waiting for fixes that have come,
    and past 2 x gps_max_gap_s of waiting they are refused as gps_gap (a replay faster than real time lost up to 100
    bearings a burst)."""

    subscription: Any = None
    first: tuple[Any, Callable[[Any, Any], None]] | None = None

    def __init__(self, handle: Callable[[Any, Any], None]):
        self.handle = handle

    def __call__(self, msg, info):
        if not self._take_first():
            return
        self.handle(msg, info)
        for k in range(1, DRAIN_MAX + 1):
            if k % FIRST_EVERY == 0 and not self._take_first():
                return
            taken = _take(self.subscription)
            if taken is None or taken is _GONE:
                return
            self.handle(*taken)

    def _take_first(self) -> bool:
        """Every message queued on `first`, handled; False when a subscription was destroyed (shutdown)."""
        if self.first is None:
            return True
        sub, handle = self.first
        for _ in range(DRAIN_MAX):
            taken = _take(sub)
            if taken is None:
                return True
            if taken is _GONE:
                return False
            handle(*taken)
        return True


_GONE = object()  # what _take gives for a subscription destroyed meanwhile


def _take(sub) -> Any:
    """The next message queued on `sub` as (message, info); None when none is; _GONE when `sub` was destroyed."""
    try:
        with sub.handle:
            return sub.handle.take_message(sub.msg_type, sub.raw)
    except InvalidHandle:  # destroyed meanwhile (shutdown)
        return _GONE


class LocalizerNode(Node):
    """Runs the Localizer on the node's inputs and publishes what it makes."""

    def __init__(self):
        # Undeclared names reach on_set_parameters, which refuses them in the engine's words ("did you mean"):
        # rclpy's own refusal names no parameter. Unknown names given at start are refused by refuse_unknown.
        super().__init__(NODE_NAME, allow_undeclared_parameters=True)
        self._init_logging()
        self._init_parameters()  # raises ConfigError: the caller refuses to start
        self.types = build.rclpy_types()
        self.monitor = NodeMonitor(self._now(), self.get_parameter("stale_after_s").value,
                                   lambda: self.get_parameter("diagnostics_period_s").value,
                                   self.get_parameter("shed_overload").value)
        self.path = VehiclePath(self.get_parameter("path_length").value,
                                lambda: self.monitor.health.valid_fix(self._now()))
        self.made: dict[str, Any] = {}  # the newest estimate of each channel made by the input being handled
        self.loc = self._new_localizer(self.cfg)
        # accepted parameters not applied yet: (config, names changed, first and last change, monotonic s)
        self.restart_due: tuple[LocalizerConfig, set, float, float] | None = None
        self.outputs = NodeOutputs(self, self.types, self.station_names, self.get_parameter("map_frame").value,
                                   self.get_parameter("emitter_frame").value, self._now)
        self.cot = self._cot_sender()  # raises ConfigError: the caller refuses to start
        self.cot_sent_at: dict[str, float] = {}  # each channel's last CoT event (monotonic s)
        self.cot_unsent = 0  # CoT events failed or dropped, as of the last /diagnostics
        self.cot_warned = False  # the last period warned of CoT: said in the log once per run of such periods
        self._init_inputs()
        self.pub_diag = self.create_publisher(self.types.DiagnosticArray, "/diagnostics", 10)
        self.diag_name = f"{self.get_fully_qualified_name().lstrip('/')}: localizer"  # like diagnostic_updater
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_service(Trigger, "~/reset_datum", self.on_reset_datum)
        self.create_timer(self.get_parameter("diagnostics_period_s").value, self.on_period)
        self.old_objects = OldObjects()
        self.idle_timer, self.idle_period = self.create_timer(IDLE_PERIOD_S, self.on_idle), IDLE_PERIOD_S
        self.last_active = time.monotonic()  # the last input or idle work (quiet_idle_period)
        self.create_timer(GOAL_PERIOD_S, self.on_goal_period)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.outputs.datum(self.loc)  # a configured datum is known at once
        self.get_logger().info(f"started: algorithm {self.cfg.algorithm}, N = {self.cfg.num_particles}, "
                               f"bearing encoding {self.cfg.bearing_encoding}")

    def _cot_sender(self) -> CotSender | None:
        """The sender of `cot_url` (None: unset); ConfigError for a URL it cannot take or without pytak."""
        url = self.get_parameter("cot_url").value
        if not url:
            return None
        try:
            return CotSender(url)
        except (ValueError, CotUnavailable) as exc:
            raise ConfigError(str(exc)) from exc

    def _send_cot(self, est) -> None:
        """A channel's estimate to TAK, at most once per cot_period_s (a failure is counted, never raised)."""
        now = time.monotonic()
        if self.cot is None or now - self.cot_sent_at.get(est.channel, -math.inf) < self.get_parameter(
                "cot_period_s").value:
            return
        self.cot_sent_at[est.channel] = now
        self.cot.send(estimate_event(est, self.get_parameter("cot_stale_s").value))

    def _init_logging(self):
        """The engine's Python log lines go to the ROS logger (console and /rosout), not a second time to the root."""
        self.log_bridge = RosLogHandler(self.get_logger())
        engine_log = logging.getLogger(ENGINE_LOGGER)
        self._engine_log_was = (engine_log.level, engine_log.propagate)
        engine_log.addHandler(self.log_bridge)
        engine_log.setLevel(logging.INFO)
        engine_log.propagate = False

    def _init_parameters(self):
        """Every parameter declared, the unknown ones refused, the engine's configuration checked as a whole."""
        declare(self, parameter_specs(), check=False)  # the engine's values are checked together, by its config
        node_values = declare(self, NODE_PARAMS)
        self.station_names, self.fixed_positions = self._stations(node_values)
        self.fix_wait = FixWait(self._feed_bearing)  # DF records that came before their fix (fix_wait.py)
        moving = [name for name in self.station_names if name not in self.fixed_positions]
        self.vehicle = moving[0] if moving else None  # the station emitter/next_goal guides
        refuse_unknown(self)
        self.cfg = self._config_from({})
        self.pending_params: dict = {}  # the first parameters of a group set together, held until it is complete
        self.crowded_said: list[str] = []  # input topics with more than one source, a twin of this node: as last logged

    def _init_inputs(self):
        """Each station's gps/fix, df/bearing and df/scan (and heading/imu for a vehicle-relative array with an IMU),
        with the input QoS parameters (sensor data: reliable and best-effort publishers both connect)."""
        T = self.types
        reliable = self.get_parameter("input_reliability").value == "reliable"
        sensor = QoSProfile(depth=self.get_parameter("input_queue_depth").value, history=HistoryPolicy.KEEP_LAST,
                            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                            durability=DurabilityPolicy.VOLATILE)
        bearing_type = T.Vector3Stamped if self.cfg.bearing_encoding == "df_record" else T.PoseWithCovarianceStamped
        lost = self.monitor.lost_counter
        self.subs: list[tuple[Any, str]] = []  # (subscription, the message type it expects)
        for name in self.station_names:  # relative names: namespaces and remaps apply
            prefix = f"{name}/" if name else ""
            on_fix = lambda msg, info, station=name: self.on_fix(msg, station, info)  # noqa: E731
            fix_sub = self.create_subscription(T.NavSatFix, prefix + "gps/fix", on_fix, sensor,
                                               event_callbacks=lost("fixes_lost"))
            on_bearing = self._draining(lambda msg, info, station=name: self.on_bearing(msg, station, info))
            bearing_sub = self.create_subscription(bearing_type, prefix + "df/bearing", on_bearing, sensor,
                                                   event_callbacks=lost("bearings_lost"))
            on_bearing.subscription, on_bearing.first = bearing_sub, (fix_sub, on_fix)
            on_scan = self._draining(lambda msg, info, station=name: self.on_scan(msg, station, info))
            scan_sub = self.create_subscription(T.PointCloud2, prefix + "df/scan", on_scan, sensor,
                                                event_callbacks=lost("bearings_lost"))
            on_scan.subscription, on_scan.first = scan_sub, (fix_sub, on_fix)
            self.subs += [(fix_sub, FIX_TYPE), (bearing_sub, INPUT_TYPES[self.cfg.bearing_encoding]),
                          (scan_sub, SCAN_TYPE)]
            if self.cfg.bearing_reference == "vehicle" and self.cfg.heading_source == "imu":
                self.create_subscription(T.Imu, prefix + "heading/imu",
                                         lambda msg, station=name: self.on_heading(msg, station), sensor)

    def _stations(self, values: dict) -> tuple[list[str], dict[str, list[float]]]:
        """The station names (or [""]: the single default station) and the fixed ones' configured positions,
        declared as `<NAME>.position`; ConfigError for duplicates or a fixed station not in `stations`."""
        names, fixed = values["stations"], values["fixed_stations"]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ConfigError(f"stations lists {', '.join(twice)} more than once")
        stray = [n for n in fixed if n not in names]
        if stray:
            raise ConfigError(f"fixed_stations {', '.join(stray)} not in stations {names}")
        specs = [ParameterSpec(f"{n}.position", STATION_POSITION.default, STATION_POSITION.spec) for n in fixed]
        given = declare(self, specs)
        positions = {}
        for n in fixed:
            pos = given[f"{n}.position"]
            if pos and len(pos) not in (2, 3):
                raise ConfigError(f"{n}.position must be [lat, lon] or [lat, lon, alt], got {pos}")
            positions[n] = pos
        return names or [""], positions

    def _new_localizer(self, cfg: LocalizerConfig, datum: LocalFrame | None = None) -> Localizer:
        """A Localizer with the node's stations declared (fixed ones at their configured positions); `datum`: the
        map frame to keep (a restart with new settings that do not move it)."""
        loc = Localizer(cfg, observer=self.path, on_estimate=self._made, live=True, datum=datum)
        for name, pos in self.fixed_positions.items():
            if not loc.add_station(name, fixed=True, position=tuple(pos) if pos else None):
                reason = next(iter(loc.view(light=True).rejected))
                raise ConfigError(f"{name}.position {pos} is not a usable position: {REASONS[reason]}")
        return loc

    def _made(self, est):
        """An estimate, kept until the input that made it is handled (_publish_made)."""
        self.made[est.channel] = est

    def destroy_node(self):
        engine_log = logging.getLogger(ENGINE_LOGGER)
        engine_log.removeHandler(self.log_bridge)
        engine_log.level, engine_log.propagate = self._engine_log_was
        self.loc.close()
        if self.cot is not None:
            self.cot.close()
        return super().destroy_node()

    # -- parameters ---------------------------------------------------------------------------------
    def _config_from(self, changes: dict) -> LocalizerConfig:
        values = {p.name: value_of(self, p) for p in ENGINE_SPECS}
        values.update(changes)
        return LocalizerConfig.from_dict(values)

    def on_set_parameters(self, params) -> SetParametersResult:
        unknown = [p.name for p in params if not self.has_parameter(p.name)]
        if unknown:
            known = self.get_parameters_by_prefix("").keys()
            return SetParametersResult(successful=False, reason=unknown_names(unknown, known))
        for p in params:
            if p.name in _NODE_SPECS:
                try:
                    _NODE_SPECS[p.name].spec.check(p.name, p.value)
                except ConfigError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        for p in params:
            if p.name == "path_length":
                self.path.resize(p.value)
            elif p.name == "stale_after_s":
                self.monitor.health.stale_after_s = p.value
            elif p.name == "shed_overload":
                self.monitor.shedding.enable(p.value)
        changes = {p.name: p.value for p in params if p.name in ENGINE_PARAMS}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            cfg = self._config_from(changes)
        except ConfigError as exc:
            waiting = self._incomplete_group(changes, exc)
            if not waiting:
                return SetParametersResult(successful=False, reason=str(exc))
            # The standard set_parameters service sets a request's parameters one at a time: the first of a
            # pair is accepted and held; the track keeps its settings until the pair is complete.
            self.pending_params = {**self.pending_params, **changes}
            self.get_logger().info(
                f"{', '.join(sorted(changes))} held until {', '.join(waiting)} are set too (they belong together)"
            )
            return SetParametersResult(successful=True)
        self.pending_params = {}
        # Accepted now, applied by the idle timer once the changes pause (RESTART_QUIET_S, at most RESTART_MAX_WAIT_S
        # after the first): a burst of sets costs one restart, the last value of each winning, not one each
        now = time.monotonic()
        _, names, first, _ = self.restart_due or (cfg, set(), now, now)
        self.restart_due = (cfg, names | changes.keys(), first, now)
        self._pace_idle(True)  # the idle tick applies them
        self.monitor.parameter_changes += 1
        return SetParametersResult(successful=True)

    def _apply_parameters(self, force: bool = False):
        """Restart the track under the accepted parameters once their changes have paused (or now, `force`)."""
        if self.restart_due is None:
            return
        cfg, names, first, last = self.restart_due
        now = time.monotonic()
        if not force and now - last < RESTART_QUIET_S and now - first < RESTART_MAX_WAIT_S:
            return
        self.restart_due = None
        old = self.loc
        old.close()
        moved = bool(names & DATUM_PARAMS)  # only datum_* move the map frame
        self.cfg = cfg
        self.loc = self._new_localizer(cfg, None if moved else old.view(light=True).frame)
        self.fix_wait.reset()  # what waited goes to the new engine; its fixes start again
        if moved:
            self.path.clear()  # drawn in the old map frame
        del old
        self.old_objects.thaw()  # the dropped Localizer's reference cycles go now
        self.outputs.datum(self.loc)
        self.monitor.restarts += 1
        self.get_logger().info(f"parameters changed ({', '.join(sorted(names))}): track restarted")

    def _incomplete_group(self, changes: dict, error: ConfigError) -> list[str]:
        """The names still missing when every change belongs to one group of parameters set together and the
        only fault is that the group is incomplete ([] otherwise: a real error)."""
        if not isinstance(error, IncompleteGroup) or not set(changes) <= set(error.group):
            return []
        given = set(changes) | set(self.pending_params)
        return [name for name in error.group if name not in given]

    # -- inputs -------------------------------------------------------------------------------------
    @staticmethod
    def _draining(handle: Callable[[Any, Any], None]) -> Drain:
        """A DF subscription's callback that also handles the records queued behind the one the executor took: a
        receiver's scan arrives as a burst (one record per channel), and the executor's wait per message would
        make the last of 50 wait for 49 of them (docs/ros.md)."""
        return Drain(handle)

    def on_fix(self, msg, station: str = "", info=None):
        t0 = time.perf_counter()
        self._pace_idle(True)
        mon = self.monitor
        mon.arrived(info, f"{station}/gps/fix")
        mon.counts["fixes_received"] += 1
        try:
            r = fix_from_navsatfix(msg)
        except (AttributeError, TypeError, ValueError):
            mon.counts["adapter_errors"] += 1
            return
        mon.fix_stamp(station, r.stamp)
        t1 = time.perf_counter()
        self.loc.add_fix(r.stamp, r.lat, r.lon, r.alt, r.status, r.sigma_m, station=station)
        mon.engine_s += time.perf_counter() - t1
        self.fix_wait.fix(station, r.stamp)  # the DF records that waited for it follow it
        self._publish_made()
        self.outputs.datum(self.loc, r.stamp)
        mon.timed(t0)

    def on_heading(self, msg, station: str = ""):
        try:
            r = heading_from_imu(msg)
        except (AttributeError, TypeError, ValueError, IndexError):
            self.monitor.counts["adapter_errors"] += 1
            return
        self.loc.add_heading(r.stamp, r.yaw_rad, station=station, variance_rad2=r.variance_rad2)

    def on_bearing(self, msg, station: str = "", info=None):
        self.monitor.counts["bearings_received"] += 1  # one that cannot be read was received all the same
        self._on_df(msg, station, info, "df/bearing", lambda m: [df_record(m, self.cfg.bearing_encoding)])

    def on_scan(self, msg, station: str = "", info=None):
        """A scan (df/scan): its records, one per channel at one stamp, each as a DF record on df/bearing, for the
        cost of one message."""
        self.monitor.counts["scans_received"] += 1
        self._on_df(msg, station, info, "df/scan", df_scan, count_records=True)

    def _on_df(self, msg, station: str, info, topic: str, records_of: Callable[[Any], list],
               count_records: bool = False):
        """A DF message's records, each stamped in the monitor and handed on (at once for a fixed station, else
        when its fix has come); one that cannot be read is an adapter error."""
        t0 = time.perf_counter()
        self._pace_idle(True)
        mon = self.monitor
        mon.arrived(info, f"{station}/{topic}")
        mon.health.reading(self._now())
        try:
            records = records_of(msg)
        except (AttributeError, TypeError, ValueError, IndexError, KeyError):
            mon.counts["adapter_errors"] += 1
            return
        if count_records:
            mon.counts["bearings_received"] += len(records)
        fixed = station in self.fixed_positions  # placed by its position: no fix to wait for
        now = time.monotonic()
        for r in records:
            mon.df_stamp(station, r.stamp, r.frequency_hz)
            if fixed:
                self._feed_bearing(station, r)
            else:
                self.fix_wait.bearing(station, r, now)
        self._publish_made()
        mon.timed(t0)

    def _feed_bearing(self, station: str, r) -> None:
        mon = self.monitor
        if not mon.shedding.keeps():  # the engine's work outruns the input: counted, said under `overload`
            return
        t1 = time.perf_counter()
        self.loc.add_bearing(r.stamp, r.azimuth_deg, r.quality, station=station, frequency_hz=r.frequency_hz,
                             sigma_deg=r.sigma_deg)
        mon.engine_s += time.perf_counter() - t1

    # -- outputs ------------------------------------------------------------------------------------
    def _publish_made(self, latency: bool = True):
        """Each channel's newest estimate made by the input just handled (a fix can close several channels'
        points), on its topics; the summary when a channel is new. `latency`: an input made them (its latency is
        counted)."""
        made, self.made = self.made, {}
        for est in made.values():
            self.outputs.estimate(self.loc, est, self.get_parameter("marker_rays").value)
            self._send_cot(est)
            if latency:
                self.monitor.published()
        if made and self.outputs.summary_due(list(made)):
            self.outputs.summary(self.loc.view())

    def _now(self) -> float:
        """The node's clock (ROS time: /clock under use_sim_time), seconds."""
        return self.get_clock().now().nanoseconds * 1e-9

    def diagnostics(self, view: LocalizerView | None = None) -> tuple[int, str, dict]:
        """(level, message, values) of the localizer's state (`view`: the Localizer's now, if not given), as
        published on /diagnostics (NodeMonitor)."""
        problems = self._publisher_problems()
        said = problems["input_publishers"] + problems["node_name"]
        if said != self.crowded_said:  # said in the log once each time it changes
            self.crowded_said = said
            for words in said:
                self.get_logger().warning(words)
        level, message, values = self.monitor.diagnostics(view or self.loc.view(), self.loc.config, self._now(),
                                                          self.pending_params, problems)
        values.update(df_waiting_for_fix=self.fix_wait.count, df_waited_for_fix=self.fix_wait.waited,
                      df_fix_wait_timed_out=self.fix_wait.timed_out)
        if self.cot is not None:  # what went to TAK, and why not
            values.update(cot_sent=self.cot.sent, cot_failed=self.cot.failed, cot_dropped=self.cot.dropped)
            if self.cot.last_error:
                values["cot_last_error"] = self.cot.last_error
            level, message = self._cot_health(level, message)
        return level, message, values

    def _cot_health(self, level: int, message: str) -> tuple[int, str]:
        """WARN, with the words in the message, while CoT events fail (until one is sent) and for a period in which
        events failed or were dropped; the log says so when such a run of periods begins (a TAK server that is down
        stays a warning while no estimate is due, not one period's)."""
        assert self.cot is not None
        unsent = self.cot.failed + self.cot.dropped
        failing, self.cot_unsent = self.cot.failing or unsent > self.cot_unsent, unsent
        if not failing:
            self.cot_warned = False
            return level, message
        words = (f"TAK: {self.cot.failed} CoT events not sent, {self.cot.dropped} dropped, to {self.cot.url} "
                 f"({self.cot.last_error or 'the sender fell behind'})")
        if not self.cot_warned:
            self.get_logger().warning(words)
        self.cot_warned = True
        return max(level, 1), (f"{message}; {words}" if message else words)

    def _publisher_problems(self) -> dict[str, list[str]]:
        """What is wrong with the publishers on our input topics, by diagnostics key: `wrong_encoding`, another
        message type (DDS never delivers them); `input_publishers`, more than one node on one topic (two sources
        mixed into one station: another graph in this ROS_DOMAIN_ID, or receivers that need a station each);
        `node_name`, another node with this one's name (they would share one /diagnostics name and one ~/reset)."""
        out: dict[str, list[str]] = {"wrong_encoding": [], "input_publishers": [], "node_name": []}
        me = (self.get_name(), self.get_namespace())
        twins = sum(1 for name, ns in self.get_node_names_and_namespaces() if (name, ns) == me)
        if twins > 1:
            full = f"{me[1].rstrip('/')}/{me[0]}"
            out["node_name"].append(
                f"{twins} nodes are named {full}: they share one /diagnostics name and one ~/reset; start each with "
                "its own name (--ros-args -r __node:=other_name) or namespace")
        for sub, want in self.subs:
            topic = sub.topic_name
            infos = self.get_publishers_info_by_topic(topic)
            for info in infos:
                if info.topic_type != want:
                    hint = next((f": start the node with -p bearing_encoding:={encoding}"
                                 for encoding, kind in INPUT_TYPES.items() if kind == info.topic_type), "")
                    out["wrong_encoding"].append(
                        f"{topic} has a {info.topic_type} publisher ({info.node_name}); expected {want}{hint}")
            # a node discovered by its endpoint before its name is each its own (rmw says _NODE_NAME_UNKNOWN_)
            nodes = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" if _UNNAMED not in i.node_name
                            else f"a node not named yet ({bytes(i.endpoint_gid[:4]).hex()})"
                            for i in infos if i.topic_type == want})
            if len(nodes) > 1:
                out["input_publishers"].append(
                    f"{topic} has {len(nodes)} publishers ({', '.join(nodes[:5])}); one source is expected: another "
                    "graph in this ROS_DOMAIN_ID, or receivers that need a station each (stations)")
        return out

    def on_idle(self):
        """Between messages: the engine's idle work (`scheduling: realtime`: the worker's finished results, one owed
        move, so the point that follows carries none and its pose is not held up); once a second, the objects that
        survived leave the garbage collector's full passes (docs/ros.md, "Latency")."""
        t0 = time.perf_counter()
        busy = self.restart_due is not None
        self._apply_parameters()
        self.fix_wait.due(time.monotonic())
        t1 = time.perf_counter()
        self.loc.idle()
        self.monitor.engine_s += time.perf_counter() - t1
        busy |= bool(self.made)
        self._publish_made(latency=False)  # no input made these: no latency to count
        grids = self.outputs.posteriors(self.loc, POSTERIOR_BUDGET_S, self.get_parameter("diagnostics_period_s").value)
        self.monitor.posterior_work.add(grids)
        self.old_objects.tick()
        self._pace_idle(busy or bool(self.fix_wait.count) or bool(grids.made or grids.deferred))
        self.monitor.other_s += time.perf_counter() - t0

    def _pace_idle(self, active: bool) -> None:
        """The idle timer's period: IDLE_PERIOD_S while the node has work or had an input within QUIET_AFTER_S,
        QUIET_IDLE_PERIOD_S once it is quiet (a worker's result or an owed move then waits up to that long)."""
        now = time.monotonic()
        if active:
            self.last_active = now
        period = quiet_idle_period(now - self.last_active)
        if period != self.idle_period:
            self.idle_period = period
            self.idle_timer.timer_period_ns = int(period * 1e9)
            self.idle_timer.reset()  # the new period from now (a changed period starts after the next tick)

    def on_period(self):
        """Every diagnostics_period_s: /diagnostics, vehicle/path if it grew, the posteriors listened to, the channel
        summary."""
        t0 = time.perf_counter()
        mon = self.monitor
        mon.period_done()
        view = self.loc.view()
        level, message, values = self.diagnostics(view)
        hardware_id = self.get_parameter("hardware_id").value
        self.pub_diag.publish(build.diagnostic_array(self.types, self._now(), self.diag_name, level, message, values,
                                                     hardware_id, mon.channel_diagnostics(view, self.diag_name)))
        mon.posterior_work = PosteriorWork()  # the grids of the period just reported
        self.outputs.paths(self.path)
        self.outputs.summary(view)
        self.outputs.drop_gone(view)
        mon.end_period(t0)

    def on_goal_period(self):
        """Once a second: where to drive next (emitter/next_goal), for the channels someone listens to, from the
        first moving station's newest fix."""
        t0 = time.perf_counter()
        vehicle = self.loc.view(light=True).vehicles.get(self.vehicle) if self.vehicle is not None else None
        self.outputs.next_goals(self.loc, vehicle, self.get_parameter("goal_radius_m").value)
        self.monitor.other_s += time.perf_counter() - t0

    def on_reset(self, request, response):
        self._apply_parameters(force=True)  # a reset acts on the parameters already accepted
        self.loc.reset()
        self.old_objects.thaw()
        response.success = True
        response.message = "track dropped; waiting for new bearings"
        self.get_logger().info(response.message)
        return response

    def on_reset_datum(self, request, response):
        """~/reset and, when the datum was not configured, drop it too: the next confirmed fix sets a new one."""
        self._apply_parameters(force=True)
        if self.cfg.has_datum:
            response.success = False
            response.message = "the datum is configured (datum_lat, datum_lon): change those parameters to move it"
            return response
        self.loc.reset(drop_datum=True)
        self.old_objects.thaw()
        self.path.clear()  # drawn in the dropped map frame
        response.success = True
        response.message = "track and datum dropped; the next confirmed fix sets the datum"
        self.get_logger().info(response.message)
        return response


def usage() -> str:
    """--help: how to start the node and every parameter with its default and valid values."""
    lines = [
        "usage: ros2 run aoa_localizer aoa_localizer [-h] [--ros-args -p NAME:=VALUE --params-file FILE -r FROM:=TO]",
        "   or: python -m aoa_localizer.node [-h] [--ros-args ...]",
        "",
        __doc__.strip(),
        "",
        "parameters (-p name:=value, or --params-file; docs: README 'Parameters'):",
    ]
    for p in parameter_specs() + NODE_PARAMS:
        default = "unset" if p.default is None else p.default
        lines.append(f"  {p.name} = {default}  ({p.spec.describe()}){'  [read-only]' if p.spec.read_only else ''}")
    return "\n".join(lines)


# The interpreter hands its lock between threads at this interval: the callback thread waits up to this long for
# it each time the global checks' worker holds it (Python's default, 5 ms, would make every message that late).
SWITCH_INTERVAL_S = 0.0005
# One owed sweep (about 2 ms at 300 points) per tick: 50 a second, several times what 50 emitters owe.
IDLE_PERIOD_S = 0.02
# A node QUIET_AFTER_S without input or idle work ticks this often: each tick is an executor's wait over every
# entity, and a node waiting for its receiver spent a share of a core on them (docs/ros.md)
QUIET_IDLE_PERIOD_S = 0.2
QUIET_AFTER_S = 1.0
POSTERIOR_BUDGET_S = 0.004  # between messages, grids are made until this is spent (at least one; the rest wait)
RESTART_QUIET_S = 0.2  # parameter changes are applied once they pause this long ...
RESTART_MAX_WAIT_S = 1.0  # ... or this long after the first of them
GOAL_PERIOD_S = 1.0  # emitter/next_goal is refreshed at most this often (s)


def quiet_idle_period(quiet_s: float) -> float:
    """The idle timer's period after `quiet_s` without input or idle work."""
    return QUIET_IDLE_PERIOD_S if quiet_s >= QUIET_AFTER_S else IDLE_PERIOD_S


def main(argv=None) -> int:
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    return run_node(NODE_NAME, LocalizerNode, spin, (ConfigError,), argv, usage())


if __name__ == "__main__":
    sys.exit(main())
