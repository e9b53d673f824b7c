"""The localizer node (`aoa_localizer`): GPS fixes and DF bearings in, the emitter's position out.

    python -m aoa_localizer.node --ros-args -p algorithm:=afsa --params-file params.yaml -r df/bearing:=/df1/bearing

Inputs `gps/fix`, `df/bearing` (sensor-data QoS: reliable and best-effort publishers both connect), or
`NAME/gps/fix`, `NAME/df/bearing` per station of `stations`; outputs `emitter/pose` (latched), `emitter/fix`,
`emitter/particles`, `emitter/markers`, the same under `emitter/<channel>/` per frequency channel, the latched
summary `emitter/channels`, `/diagnostics` at 1 Hz; services `~/reset` and `~/reset_datum`. Every
LocalizerConfig field is a parameter (a filter's own settings as `<filter>.*`); a changed parameter restarts the
track with the new settings, an invalid one is refused with its reason.
"""

from __future__ import annotations

import json
import logging
import math
import sys
import time
from collections import OrderedDict
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np
import rclpy
from rcl_interfaces.msg import (
    SetParametersResult,
)
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from aoa_localizer.core.spec import ConfigError, IncompleteGroup, ParameterSpec
from aoa_localizer.engine.channels import DEFAULT
from aoa_localizer.engine.config import LocalizerConfig, parameter_specs
from aoa_localizer.engine.crlb import ELLIPSE_95, ellipse_axes, ellipse_points
from aoa_localizer.engine.input_guard import StampGaps
from aoa_localizer.engine.localizer import REASONS, Localizer
from aoa_localizer.engine.memory import OldObjects, keep_freed_memory
from aoa_localizer.engine.noise import sentence as noise_sentence
from aoa_localizer.ros.declare import declare, refuse_unknown
from aoa_localizer.ros.node_health import LatencyHistogram, NodeHealth, Overload
from aoa_localizer.ros.node_params import NODE_PARAMS, STATION_POSITION
from aoa_localizer.ros.ros_main import run_node
from aoa_localizer.ros.vehicle_path import VehiclePath
from msgs_adapters import build
from msgs_adapters.fields import (
    bearing_from_pose,
    df_from_vector3stamped,
    fix_from_navsatfix,
    heading_from_imu,
)

NODE_NAME = "aoa_localizer"
_MAX_LOAD = 0.8  # share of wall time spent working (inputs, idle moves, diagnostics) above which it warns
_STALL_PERIODS = 2.0  # a diagnostics period this many times longer than configured: the node was held up
_GAP_FACTOR = 1.5  # a stamp gap this many typical intervals long holds lost records (a regular receiver jitters less)
_GAP_STREAMS = 256  # input streams whose stamp gaps are followed; past it the one heard least recently is dropped
DATUM_PARAMS = frozenset({"datum_lat", "datum_lon", "datum_alt"})  # the only parameters that move the map frame
INPUT_TYPES = {"df_record": "geometry_msgs/msg/Vector3Stamped", "pose": "geometry_msgs/msg/PoseWithCovarianceStamped"}
FIX_TYPE = "sensor_msgs/msg/NavSatFix"
DRAIN_MAX = 100  # DF records handled per executor callback beyond the first (then GPS, timers and services get a turn)

_NODE_SPECS = {p.name: p for p in NODE_PARAMS}


ENGINE_PARAMS = frozenset(p.name for p in parameter_specs())


class RosLogHandler(logging.Handler):
    """Python logging records (the engine's: datum set, filter started, re-starts) forwarded to a ROS logger, so
    they reach the console and /rosout like the node's own lines."""

    def __init__(self, ros_logger):
        super().__init__()
        self.ros_logger = ros_logger

    def emit(self, record: logging.LogRecord):
        # One call line per severity: rclpy keys its log settings on the calling line and raises "Logger severity
        # cannot be changed between calls" when one line logs at two severities (it crashed the node's callback).
        level, ros, text = record.levelno, self.ros_logger, f"{record.name}: {record.getMessage()}"
        if level >= logging.ERROR:
            ros.error(text)
        elif level >= logging.WARNING:
            ros.warning(text)
        elif level >= logging.INFO:
            ros.info(text)
        else:
            ros.debug(text)


class Drain:
    """Handle the message the executor took, then up to DRAIN_MAX more already queued on `subscription`."""

    subscription: Any = None

    def __init__(self, handle: Callable[[Any, Any], None]):
        self.handle = handle

    def __call__(self, msg, info):
        self.handle(msg, info)
        sub = self.subscription
        for _ in range(DRAIN_MAX):
            try:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:  # destroyed meanwhile (shutdown)
                return
            if taken is None:
                return
            self.handle(*taken)


class LocalizerNode(Node):
    """Runs the Localizer on the node's inputs and publishes what it makes."""

    def __init__(self):
        super().__init__(NODE_NAME)
        self.log_bridge = RosLogHandler(self.get_logger())
        engine_log = logging.getLogger("aoa_localizer")
        self._engine_log_was = (engine_log.level, engine_log.propagate)
        engine_log.addHandler(self.log_bridge)
        engine_log.setLevel(logging.INFO)
        engine_log.propagate = False  # the ROS logger prints it; no second copy through the root handler
        declare(self, parameter_specs(), check=False)  # the engine's values are checked together, by its config
        node_values = declare(self, NODE_PARAMS)  # raises ConfigError: the caller refuses to start
        self.station_names, self.fixed_positions = self._stations(node_values)
        refuse_unknown(self)
        self.cfg = self._config_from({})  # raises ConfigError too
        self.map_frame = self.get_parameter("map_frame").value
        self.emitter_frame = self.get_parameter("emitter_frame").value
        self.diag_name = f"{self.get_fully_qualified_name().lstrip('/')}: localizer"  # like diagnostic_updater
        self.datum_sent: Any = None  # the LocalFrame last published on emitter/datum
        self.health = NodeHealth(self._now(), self.get_parameter("stale_after_s").value)
        self.path = VehiclePath(self.get_parameter("path_length").value, lambda: self.health.valid_fix(self._now()))
        self.made: dict[str, Any] = {}  # the newest estimate of each channel made by the input being handled
        self.loc = self._new_localizer(self.cfg)
        self.channel_pubs: dict[str, SimpleNamespace] = {}
        self.summary_sent: Any = None  # the channel summary last published on emitter/channels
        self.T = build.rclpy_types()
        self.counts = {
            "fixes_received": 0,
            "bearings_received": 0,
            "adapter_errors": 0,
            "fixes_lost": 0,
            "bearings_lost": 0,
        }
        self.lost_reported = 0  # fixes_lost + bearings_lost at the last diagnostics
        self.df_gaps: OrderedDict[tuple[str, float], StampGaps] = OrderedDict()  # per station and frequency
        self.fix_gaps: OrderedDict[tuple[str, float], StampGaps] = OrderedDict()  # per station
        self.callback_s: list[float] = []
        self.other_s = 0.0  # work in the period outside the input callbacks: idle moves, the periodic work
        self.period_start = time.perf_counter()
        self.overload = Overload()
        self.arrival_ns = time.time_ns()
        self.latency_ms: list[float] = []  # from a message's arrival to the publication of each pose it made
        self.latency_since_start = LatencyHistogram()
        self.pending_params: dict = {}  # the first parameters of a group set together, held until it is complete
        self.callback_max_s = 0.0

        depth = self.get_parameter("input_queue_depth").value
        reliable = self.get_parameter("input_reliability").value == "reliable"
        sensor = QoSProfile(
            depth=depth,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            history=HistoryPolicy.KEEP_LAST,
            durability=DurabilityPolicy.VOLATILE,
        )
        latched = QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )
        self.latched = latched
        bearing_type = (
            self.T.Vector3Stamped if self.cfg.bearing_encoding == "df_record" else self.T.PoseWithCovarianceStamped
        )
        self.subs: list[tuple[Any, str]] = []  # (subscription, the message type it expects)
        self.pub_path: dict[str, Any] = {}
        for name in self.station_names:  # relative names: namespaces and remaps apply
            prefix = f"{name}/" if name else ""
            fix_sub = self.create_subscription(self.T.NavSatFix, prefix + "gps/fix",
                                               lambda msg, info, station=name: self.on_fix(msg, station, info),
                                               sensor,
                                               event_callbacks=self._lost_counter("fixes_lost"))
            on_bearing = self._draining(lambda msg, info, station=name: self.on_bearing(msg, station, info))
            bearing_sub = self.create_subscription(bearing_type, prefix + "df/bearing", on_bearing, sensor,
                                                   event_callbacks=self._lost_counter("bearings_lost"))
            on_bearing.subscription = bearing_sub
            self.subs += [(fix_sub, FIX_TYPE), (bearing_sub, INPUT_TYPES[self.cfg.bearing_encoding])]
            # A vehicle-relative DF array with an IMU: the heading comes on heading/imu (REP-103 yaw).
            if self.cfg.bearing_reference == "vehicle" and self.cfg.heading_source == "imu":
                self.create_subscription(self.T.Imu, prefix + "heading/imu",
                                         lambda msg, station=name: self.on_heading(msg, station), sensor)
            self.pub_path[name] = self.create_publisher(self.T.Path, prefix + "vehicle/path", 1)
        self.channel_pubs[DEFAULT] = self._channel_publishers("emitter/")
        self.pub_channels = self.create_publisher(self.T.String, "emitter/channels", latched)
        self.pub_datum = self.create_publisher(self.T.NavSatFix, "emitter/datum", latched)
        self.pub_diag = self.create_publisher(self.T.DiagnosticArray, "/diagnostics", 10)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_service(Trigger, "~/reset_datum", self.on_reset_datum)
        self.create_timer(self.get_parameter("diagnostics_period_s").value, self.on_period)
        self.old_objects = OldObjects()
        self.create_timer(IDLE_MOVES_PERIOD_S, self.on_idle)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self._publish_datum()  # a configured datum is known at once
        self.get_logger().info(
            f"started: algorithm {self.cfg.algorithm}, N = {self.cfg.num_particles}, "
            f"bearing encoding {self.cfg.bearing_encoding}"
        )

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

    def _new_localizer(self, cfg: LocalizerConfig) -> Localizer:
        """A Localizer with the node's stations declared (fixed ones at their configured positions)."""
        loc = Localizer(cfg, observer=self.path, on_estimate=self._made, live=True)
        for name, pos in self.fixed_positions.items():
            loc.add_station(name, fixed=True)
            if pos and not loc.set_station_position(name, *pos):
                reason = next(iter(loc.rejected))
                raise ConfigError(f"{name}.position {pos} is not a usable position: {REASONS[reason]}")
        return loc

    @staticmethod
    def _gaps(streams: OrderedDict, station: str, frequency_hz: float = math.nan) -> StampGaps:
        """The stamp gaps of one input stream: a station's fixes, or its DF records of one frequency (NaN: the
        default channel); the _GAP_STREAMS heard most recently are kept."""
        key = (station, frequency_hz if math.isfinite(frequency_hz) else 0.0)
        gaps = streams.get(key)
        if gaps is None:
            gaps = streams[key] = StampGaps(factor=_GAP_FACTOR)
            if len(streams) > _GAP_STREAMS:
                streams.popitem(last=False)
        else:
            streams.move_to_end(key)
        return gaps

    def _made(self, est):
        """An estimate, kept until the input that made it is handled (_publish_made)."""
        self.made[est.channel] = est

    def _channel_publishers(self, prefix: str) -> SimpleNamespace:
        """pose (latched), fix, particles and markers under `prefix` (emitter/ or emitter/<channel>/). A frequency
        channel's publishers go without rclpy's default QoS-event handlers: each is a waitable the executor walks
        at every message, and 50 channels' 200 of them took most of the node's time."""
        T = self.T
        events = PublisherEventCallbacks(use_default_callbacks=prefix == "emitter/")

        def make(kind, topic, qos):
            return self.create_publisher(kind, prefix + topic, qos, event_callbacks=events)

        return SimpleNamespace(pose=make(T.PoseWithCovarianceStamped, "pose", self.latched),
                               fix=make(T.NavSatFix, "fix", self.latched), particles=make(T.PoseArray, "particles", 10),
                               markers=make(T.MarkerArray, "markers", 10))

    def destroy_node(self):
        engine_log = logging.getLogger("aoa_localizer")
        engine_log.removeHandler(self.log_bridge)
        engine_log.level, engine_log.propagate = self._engine_log_was
        self.loc.close()
        return super().destroy_node()

    # -- parameters ---------------------------------------------------------------------------------
    def _config_from(self, changes: dict) -> LocalizerConfig:
        values = {name: self.get_parameter(name).value for name in ENGINE_PARAMS}
        values.update(changes)
        return LocalizerConfig.from_dict(values)

    def on_set_parameters(self, params) -> SetParametersResult:
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
                self.health.stale_after_s = p.value
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
        old = self.loc
        old.close()
        self.cfg, self.loc = cfg, self._new_localizer(cfg)
        if changes.keys() & DATUM_PARAMS:
            self.path.clear()  # drawn in the old map frame
        else:
            self.loc.adopt_datum(old.frame)  # only datum_* move the map frame
        del old
        self.old_objects.thaw()  # the dropped Localizer's reference cycles go now
        self._publish_datum()
        self.get_logger().info(f"parameters changed ({', '.join(sorted(changes))}): track restarted")
        return SetParametersResult(successful=True)

    def _incomplete_group(self, changes: dict, error: ConfigError) -> list[str]:
        """The names still missing when every change belongs to one group of parameters set together and the
        only fault is that the group is incomplete ([] otherwise: a real error)."""
        if not isinstance(error, IncompleteGroup) or not set(changes) <= set(error.group):
            return []
        given = set(changes) | set(self.pending_params)
        return [name for name in error.group if name not in given]

    # -- inputs -------------------------------------------------------------------------------------
    def _lost_counter(self, key: str) -> SubscriptionEventCallbacks:
        """The middleware's message-lost events of a subscription, counted under `key`."""

        def on_lost(status):
            self.counts[key] += int(status.total_count_change)

        return SubscriptionEventCallbacks(message_lost=on_lost)

    @staticmethod
    def _draining(handle: Callable[[Any, Any], None]) -> Drain:
        """A DF subscription's callback that also handles the records queued behind the one the executor took: a
        receiver's scan arrives as a burst (one record per channel), and the executor's wait per message would
        make the last of 50 wait for 49 of them (docs/ros.md)."""
        return Drain(handle)

    def _arrived(self, info) -> None:
        """When the message being handled reached this process (the middleware's receive time, else now): the
        start of the latency of any pose it produces."""
        received = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
        self.arrival_ns = received if received > 0 else time.time_ns()

    def on_fix(self, msg, station: str = "", info=None):
        t0 = time.perf_counter()
        self._arrived(info)
        self.counts["fixes_received"] += 1
        try:
            r = fix_from_navsatfix(msg)
        except (AttributeError, TypeError, ValueError):
            self.counts["adapter_errors"] += 1
            return
        if math.isfinite(r.stamp):
            self._gaps(self.fix_gaps, station).add(r.stamp)
        self.loc.add_fix(r.stamp, r.lat, r.lon, r.alt, r.status, r.sigma_m, station=station)
        self._publish_made()
        self._publish_datum()
        self._timed(t0)

    def on_heading(self, msg, station: str = ""):
        try:
            r = heading_from_imu(msg)
        except (AttributeError, TypeError, ValueError, IndexError):
            self.counts["adapter_errors"] += 1
            return
        self.loc.add_heading(r.stamp, r.yaw_rad, station=station)

    def on_bearing(self, msg, station: str = "", info=None):
        t0 = time.perf_counter()
        self._arrived(info)
        self.counts["bearings_received"] += 1
        self.health.reading(self._now())
        try:
            if self.cfg.bearing_encoding == "df_record":
                r = df_from_vector3stamped(msg)
                if math.isfinite(r.stamp):
                    self._gaps(self.df_gaps, station, r.frequency_hz).add(r.stamp)
                self.loc.add_bearing(r.stamp, r.azimuth_deg, r.quality, station=station, frequency_hz=r.frequency_hz)
            else:
                p = bearing_from_pose(msg)
                if math.isfinite(p.stamp):
                    self._gaps(self.df_gaps, station).add(p.stamp)
                self.loc.add_bearing_enu(p.stamp, p.yaw_rad, p.variance_rad2, station=station)
        except (AttributeError, TypeError, ValueError):
            self.counts["adapter_errors"] += 1
            return
        self._publish_made()
        self._timed(t0)

    def _timed(self, t0: float):
        dt = time.perf_counter() - t0
        self.callback_s.append(dt)
        self.callback_max_s = max(self.callback_max_s, dt)

    # -- outputs ------------------------------------------------------------------------------------
    def _publish_made(self):
        """Each channel's newest estimate made by the input just handled (a fix can close several channels'
        points), on its topics; the summary when a channel is new."""
        made, self.made = self.made, {}
        for est in made.values():
            self._publish(est)
            self.latency_ms.append(1e-6 * (time.time_ns() - self.arrival_ns))
        if any(self.summary_sent is None or c not in self.summary_sent for c in made):
            self._publish_summary()

    def _publish(self, est):
        """An estimate on its channel's topics, and on emitter/ too when its channel is the primary one."""
        pubs = self.channel_pubs.get(est.channel)
        if pubs is None:
            pubs = self.channel_pubs[est.channel] = self._channel_publishers(f"emitter/{est.channel}/")
        self._publish_on(pubs, est)
        if est.channel != DEFAULT and getattr(self.loc.channels.primary(), "id", None) == est.channel:
            self._publish_on(self.channel_pubs[DEFAULT], est)  # emitter/ carries the primary channel

    def _publish_on(self, pubs: SimpleNamespace, est):
        """The estimate on one set of publishers (a channel's, or emitter/ for the primary channel)."""
        T = self.T
        frame = self.map_frame
        pubs.pose.publish(build.emitter_pose(T, est, frame))
        pubs.fix.publish(build.emitter_fix(T, est, self.loc.datum_frame().alt0, self.emitter_frame))
        # The cloud and the markers cost about 1 ms to build: only for someone listening.
        if pubs.particles.get_subscription_count():
            pubs.particles.publish(build.particle_array(T, est, frame))
        if pubs.markers.get_subscription_count():
            rays = self.loc.recent_points(self.get_parameter("marker_rays").value, est.channel)[:, :3]
            ring = ellipse_points((est.east, est.north), est.cov, ELLIPSE_95)
            pubs.markers.publish(build.markers(T, est, rays, ring, frame))

    def channel_summary(self) -> dict[str, dict]:
        """Every channel with an estimate: its frequency, topics, state (live or retired) and latest estimate."""
        out = {}
        for channel in self.loc.channels.all():
            est = channel.estimate
            if est is None:
                continue
            out[channel.id] = {
                "frequency_hz": channel.frequency_hz if math.isfinite(channel.frequency_hz) else None,
                "topics": "emitter/" if channel.id == DEFAULT else f"emitter/{channel.id}/",
                "state": "retired" if channel.retired else "live",
                "stamp": est.stamp, "lat": est.lat, "lon": est.lon, "east": round(est.east, 2),
                "north": round(est.north, 2), "ellipse95_major_m": round(float(ellipse_axes(est.cov)[0]), 2),
                "points_used": est.points_used,
            }
        return out

    def _publish_summary(self):
        """emitter/channels (latched std_msgs/String): a JSON object of the channels, when it changed."""
        summary = self.channel_summary()
        if summary != self.summary_sent:
            self.pub_channels.publish(self.T.String(data=json.dumps({"channels": summary}, sort_keys=True)))
            self.summary_sent = summary

    def _publish_datum(self):
        """emitter/datum (latched) whenever the map frame's origin is new: set from a fix, or configured."""
        datum = self.loc.frame
        if datum is not None and datum != self.datum_sent:
            self.pub_datum.publish(build.datum_fix(self.T, self._now(), datum.lat0, datum.lon0, datum.alt0,
                                                   self.map_frame))
            self.datum_sent = datum

    def _publish_path(self):
        """Each station's vehicle/path when a fix was added since the last one and someone listens (a full path each
        time: Path has no deltas, and 1000 poses cost about 15 ms to build)."""
        for station, poses in self.path.new_paths().items():
            pub = self.pub_path.get(station)
            if pub is not None and pub.get_subscription_count():
                pub.publish(build.vehicle_path(self.T, poses[-1][0], poses, self.map_frame))

    def _now(self) -> float:
        """The node's clock (ROS time: /clock under use_sim_time), seconds."""
        return self.get_clock().now().nanoseconds * 1e-9

    def diagnostics(self) -> tuple[int, str, dict]:
        """(level, message, values) of the localizer's state, as published on /diagnostics: WARN before the first
        estimate, while a global check runs, and while any warning holds (its words join the message)."""
        loc = self.loc
        values = self._state_values()
        values.update(self._robustness_values())
        if self.pending_params:
            values["parameters_held"] = ", ".join(sorted(self.pending_params)) + " (waiting for the rest of the group)"
        values.update(df_stamp_gaps=sum(g.gaps for g in self.df_gaps.values()),
                      df_missing_by_stamp=sum(g.missing for g in self.df_gaps.values()),
                      fix_stamp_gaps=sum(g.gaps for g in self.fix_gaps.values()),
                      fixes_missing_by_stamp=sum(g.missing for g in self.fix_gaps.values()))
        now = self._now()
        self.health.count_restarts(now, loc.events + loc.rejected)
        warnings = self._warnings() + self.health.stale(now)
        error = self.health.restart_error()
        if error:
            warnings.append(("restarting", *error))
        values.update({key: value for key, value, _ in warnings})
        checking = loc.track_status().alarm  # the cloud no longer explains the newest points
        est = loc.estimate
        if est is not None:
            values["state"] = est.state
            warnings += [(f"warning_{i}", text, text) for i, text in enumerate(est.warnings)]
        suspect = est is not None and est.state == "suspect"
        level = 2 if error else 1 if est is None or checking or warnings or suspect else 0
        return level, "; ".join([loc.status] + [words for _, _, words in warnings]), values

    def _state_values(self) -> dict[str, Any]:
        """Counts, rejections by reason, callback load and the estimate."""
        loc = self.loc
        values: dict[str, Any] = dict(self.counts)
        values.update(status=loc.status, algorithm=self.cfg.algorithm, bearings_used=loc.bearings_used,
                      points_used=loc.points_used, unknown_quality=loc.unknown_quality,
                      bearings_rejected=sum(v for k, v in loc.rejected.items() if not k.startswith("fix_")),
                      fixes_rejected=sum(v for k, v in loc.rejected.items() if k.startswith("fix_")))
        values.update({f"rejected.{k}": v for k, v in sorted(loc.rejected.items())})
        if self.callback_s:
            values.update(callback_mean_ms=f"{1e3 * sum(self.callback_s) / len(self.callback_s):.3f}",
                          callback_max_ms=f"{1e3 * self.callback_max_s:.3f}",
                          callbacks_in_period=len(self.callback_s))
        values.update(load_pct=f"{100 * self._load():.0f}", period_s=f"{time.perf_counter() - self.period_start:.3f}",
                      rejected_while_overloaded=sum(self.overload.rejected.values()))
        if self.latency_ms:
            p50, p99, top = np.percentile(self.latency_ms, (50, 99, 100), method="higher")
            values.update(poses_in_period=len(self.latency_ms), pose_latency_p50_ms=f"{p50:.3f}",
                          pose_latency_p99_ms=f"{p99:.3f}", pose_latency_max_ms=f"{top:.3f}")
        if self.latency_since_start.total:
            values.update(poses_since_start=self.latency_since_start.total,
                          pose_latency_p99_ms_since_start=f"{self.latency_since_start.percentile(99):.3f}")
        est = loc.estimate
        if est is not None:
            values.update(ess=f"{est.ess:.1f}", update_ms=f"{1e3 * loc.last_update_s:.3f}", east=f"{est.east:.2f}",
                          north=f"{est.north:.2f}", lat=f"{est.lat:.7f}", lon=f"{est.lon:.7f}",
                          ellipse95_major_m=f"{ellipse_axes(est.cov)[0]:.2f}")
        return values

    def _load(self) -> float:
        """Share of the period since the last diagnostics spent working: input callbacks, idle moves and the
        periodic work (a period the node was held up in lasts longer than configured: its wall time counts)."""
        period = max(time.perf_counter() - self.period_start, self.get_parameter("diagnostics_period_s").value)
        return (sum(self.callback_s) + self.other_s) / period

    def _warnings(self) -> list[tuple[str, str, str]]:
        """(key, value, words for the status message) of each warning that holds now."""
        out = []
        wrong = self._wrong_publishers()
        if wrong:
            out.append(("wrong_encoding", "; ".join(wrong), wrong[0]))
        overload = self._overload()
        if overload:
            out.append(("overload", overload, "the node cannot keep up with its inputs"))
        lost = self.counts["fixes_lost"] + self.counts["bearings_lost"]
        if lost > self.lost_reported:
            out.append(("messages_lost", f"{lost - self.lost_reported} input messages lost by the middleware in the "
                        "last period (network, or input_queue_depth too small for the load)",
                        "input messages are being lost"))
        self.lost_reported = lost
        clock = self.loc.clock_hint_sentence()
        if clock:
            out.append(("clock_offset", clock, "the DF stamps look offset from the GPS clock"))
        return out

    def _overload(self) -> str | None:
        """Why the node could not keep up in this period (its work over _MAX_LOAD of the wall time, or the period
        held up), with the inputs refused meanwhile; the words hold one more period, since what a stall lost is
        refused while its backlog is worked off. None when it kept up."""
        period = self.get_parameter("diagnostics_period_s").value
        wall = time.perf_counter() - self.period_start
        load = self._load()
        cause = None
        if wall > _STALL_PERIODS * period:
            cause = f"the node was held up: this diagnostics period lasted {wall:.1f} s ({period:g} s configured)"
        elif load > _MAX_LOAD:
            cause = f"the node worked {100 * load:.0f} % of the last period"
        return self.overload.judge(cause, self.loc.rejected, self._missing())

    def _missing(self) -> int:
        """Inputs that never arrived, as far as anything can tell: the middleware's lost counts and stamp gaps."""
        return (self.counts["fixes_lost"] + self.counts["bearings_lost"]
                + sum(g.missing for g in self.df_gaps.values()) + sum(g.missing for g in self.fix_gaps.values()))

    def _robustness_values(self) -> dict:
        """Self-calibrated noise, modes, the health test and the robustness events, as diagnostic values."""
        loc = self.loc
        values: dict[str, Any] = {}
        if self.cfg.calibrate_noise:
            noise = loc.noise_summary()
            values["noise"] = noise_sentence(noise)
            values.update({f"noise.sigma_deg.q{k}": v for k, v in noise["sigma_deg"].items()})
            values.update(
                {
                    "noise.reading_outlier_prob": noise["reading_outlier_prob"],
                    "noise.point_outlier_prob": noise["point_outlier_prob"],
                }
            )
        values["health.recent_outlier_share"] = f"{loc.track_status().outlier_share:.2f}"
        est = loc.estimate
        if est is not None:
            values["modes"] = len(est.modes)
            values.update(
                {f"mode.{i + 1}": f"E {e:.1f} N {n:.1f} mass {m:.3f}" for i, (e, n, m) in enumerate(est.modes)}
            )
        values.update({f"events.{k}": v for k, v in sorted(loc.events.items())})
        return values

    def _wrong_publishers(self) -> list[str]:
        """Publishers on our input topics with another message type (DDS never delivers them)."""
        out = []
        for sub, want in self.subs:
            topic = sub.topic_name
            for info in self.get_publishers_info_by_topic(topic):
                if info.topic_type != want:
                    out.append(f"{topic} has a {info.topic_type} publisher ({info.node_name}); expected {want}")
        return out

    def on_idle(self):
        """Between messages: one move a channel owes (`scheduling: realtime`: a resampling's sweep, a worker check's
        move), so the point that follows carries none and its pose is not held up; once a second, the objects that
        survived leave the garbage collector's full passes (docs/ros.md, "Latency")."""
        t0 = time.perf_counter()
        self.loc.pay_owed()
        self.old_objects.tick()
        self.other_s += time.perf_counter() - t0

    def on_period(self):
        """Every diagnostics_period_s: the worker's finished results of channels whose data paused, /diagnostics,
        and vehicle/path if it grew."""
        t0 = time.perf_counter()
        self.loc.poll()
        made, self.made = self.made, {}
        for est in made.values():  # no input made these: no latency to count
            self._publish(est)
        self.latency_since_start.add(self.latency_ms)
        level, message, values = self.diagnostics()
        hardware_id = self.get_parameter("hardware_id").value
        self.pub_diag.publish(build.diagnostic_array(self.T, self._now(), self.diag_name, level, message, values,
                                                     hardware_id, self.channel_diagnostics()))
        self.callback_s, self.callback_max_s, self.latency_ms = [], 0.0, []
        self._publish_path()
        self._publish_summary()
        self._drop_gone_publishers()
        self.period_start = time.perf_counter()
        self.other_s = self.period_start - t0  # this period's own work counts in the next one

    def _drop_gone_publishers(self):
        """The publishers of channels the engine no longer keeps (retired long ago): memory stays bounded under a
        stream of ever new frequencies."""
        kept = {c.id for c in self.loc.channels.all()} | {DEFAULT}
        for cid in [cid for cid in self.channel_pubs if cid not in kept]:
            for pub in vars(self.channel_pubs.pop(cid)).values():
                self.destroy_publisher(pub)

    def channel_diagnostics(self) -> list[tuple[str, int, str, dict]]:
        """One status per frequency channel: WARN before its first estimate or while its check runs, OK tracking
        or retired."""
        out = []
        for channel in self.loc.channels.all():
            if channel.id == DEFAULT:
                continue
            track, est = self.loc.track_status(channel), channel.estimate
            values: dict[str, Any] = {"frequency_hz": f"{channel.frequency_hz:.0f}", "status": track.text,
                                      "bearings_used": track.bearings_used, "points_used": track.points_used,
                                      "topics": f"emitter/{channel.id}/"}
            if est is not None:
                values.update(east=f"{est.east:.2f}", north=f"{est.north:.2f}", lat=f"{est.lat:.7f}",
                              lon=f"{est.lon:.7f}", ellipse95_major_m=f"{ellipse_axes(est.cov)[0]:.2f}")
            level = 0 if channel.retired else 1 if est is None or track.alarm else 0
            message = f"retired (silent for channel_timeout_s); {track.text}" if channel.retired else track.text
            out.append((f"{self.diag_name} channel {channel.id}", level, message, values))
        return out

    def on_reset(self, request, response):
        self.loc.reset()
        self.old_objects.thaw()
        response.success = True
        response.message = "track dropped; waiting for new bearings"
        self.get_logger().info(response.message)
        return response

    def on_reset_datum(self, request, response):
        """~/reset and, when the datum was not configured, drop it too: the next confirmed fix sets a new one."""
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
IDLE_MOVES_PERIOD_S = 0.02


def main(argv=None) -> int:
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    keep_freed_memory()
    return run_node(NODE_NAME, LocalizerNode, rclpy.spin, (ConfigError,), argv, usage())


if __name__ == "__main__":
    sys.exit(main())
