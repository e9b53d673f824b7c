"""The localizer node (`aoa_localizer`): GPS fixes and DF bearings in, the emitter's position out.

    python -m aoa_localizer.node --ros-args -p algorithm:=afsa --params-file params.yaml -r df/bearing:=/df1/bearing

Inputs `gps/fix`, `df/bearing` (sensor-data QoS: reliable and best-effort publishers both connect);
outputs `emitter/pose` (latched), `emitter/fix`, `emitter/particles`, `emitter/markers`, `/diagnostics`
at 1 Hz; services `~/reset` and `~/reset_datum`. Every LocalizerConfig field is a parameter (fish-school ones as `afsa.*`);
a changed parameter restarts the track with the new settings, an invalid one is refused with its reason.
"""
from __future__ import annotations

import sys
import time
from dataclasses import fields

import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from msgs_adapters import build
from msgs_adapters.fields import (
    bearing_from_pose,
    df_from_vector3stamped,
    fix_from_navsatfix,
)

from aoa_localizer.engine.config import ConfigError, LocalizerConfig, ParameterSpec, parameter_specs
from aoa_localizer.engine.crlb import ELLIPSE_95, ellipse_axes, ellipse_points
from aoa_localizer.engine.input_guard import StampGaps
from aoa_localizer.engine.localizer import Localizer
from aoa_localizer.ros.node_params import NODE_PARAMS
from aoa_localizer.engine.noise import sentence as noise_sentence
from aoa_localizer.ros.ros_main import run_node

NODE_NAME = "aoa_localizer"
PAIRED = (("datum_lat", "datum_lon"), ("prior_east", "prior_north", "prior_sigma_m"))  # set together
_MAX_LOAD = 0.8  # share of wall time in input callbacks above which /diagnostics warns
DIAG_NAME = "aoa_localizer: localizer"
INPUT_TYPES = {"df_record": "geometry_msgs/msg/Vector3Stamped", "pose": "geometry_msgs/msg/PoseWithCovarianceStamped"}
FIX_TYPE = "sensor_msgs/msg/NavSatFix"

_NODE_SPECS = {p.name: p for p in NODE_PARAMS}


def _descriptor(p: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of a declared parameter: its meaning, read_only when fixed at start, its range when
    closed on both sides (ROS ranges cannot be open; the engine's check refuses the rest with the reason)."""
    spec = p.spec
    d = ParameterDescriptor(description=spec.doc.replace("`", ""), read_only=spec.read_only)
    if p.default is None:
        d.dynamic_typing = True  # unset until given; then any number
    closed = not (spec.low_open or spec.high_open) and spec.low is not None and spec.high is not None
    if closed and spec.kind is int:
        d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
    elif closed and spec.kind is float:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    if spec.choices:
        d.additional_constraints = f"one of {', '.join(spec.choices)}"
    return d


ENGINE_PARAMS = frozenset(p.name for p in parameter_specs())


class LocalizerNode(Node):
    """Runs the Localizer on the node's inputs and publishes what it makes."""

    def __init__(self):
        super().__init__(NODE_NAME)
        for p in parameter_specs() + NODE_PARAMS:
            self.declare_parameter(p.name, p.default, _descriptor(p))
        for p in NODE_PARAMS:  # a node-only value is checked like an engine one: refused at start with the reason
            p.spec.check(p.name, self.get_parameter(p.name).value)
        self.cfg = self._config_from({})  # raises ConfigError: the caller refuses to start
        self.loc = Localizer(self.cfg)
        self.T = build.rclpy_types()
        self.counts = {"fixes_received": 0, "bearings_received": 0, "adapter_errors": 0, "fixes_lost": 0,
                       "bearings_lost": 0}
        self.lost_reported = 0  # fixes_lost + bearings_lost at the last diagnostics
        self.df_gaps = StampGaps()
        self.callback_s: list[float] = []
        self.pending_params: dict = {}  # the first parameters of a group set together, held until it is complete
        self.callback_max_s = 0.0

        depth = self.get_parameter("input_queue_depth").value
        sensor = QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                            durability=DurabilityPolicy.VOLATILE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.fix_sub = self.create_subscription(self.T.NavSatFix, "gps/fix", self.on_fix, sensor,
                                                event_callbacks=self._lost_counter("fixes_lost"))
        bearing_type = self.T.Vector3Stamped if self.cfg.bearing_encoding == "df_record" else self.T.PoseWithCovarianceStamped
        self.bearing_sub = self.create_subscription(bearing_type, "df/bearing", self.on_bearing, sensor,
                                                    event_callbacks=self._lost_counter("bearings_lost"))
        self.pub_pose = self.create_publisher(self.T.PoseWithCovarianceStamped, "emitter/pose", latched)
        self.pub_fix = self.create_publisher(self.T.NavSatFix, "emitter/fix", 10)
        self.pub_particles = self.create_publisher(self.T.PoseArray, "emitter/particles", 10)
        self.pub_markers = self.create_publisher(self.T.MarkerArray, "emitter/markers", 10)
        self.pub_diag = self.create_publisher(self.T.DiagnosticArray, "/diagnostics", 10)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_service(Trigger, "~/reset_datum", self.on_reset_datum)
        self.create_timer(self.get_parameter("diagnostics_period_s").value, self.publish_diagnostics)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.get_logger().info(f"started: algorithm {self.cfg.algorithm}, N = {self.cfg.num_particles}, "
                               f"bearing encoding {self.cfg.bearing_encoding}")

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
        changes = {p.name: p.value for p in params if p.name in ENGINE_PARAMS}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            cfg = self._config_from(changes)
        except ConfigError as exc:
            waiting = self._incomplete_pair(changes, str(exc))
            if not waiting:
                return SetParametersResult(successful=False, reason=str(exc))
            # The standard set_parameters service sets a request's parameters one at a time: the first of a
            # pair is accepted and held; the track keeps its settings until the pair is complete.
            self.pending_params = {**self.pending_params, **changes}
            self.get_logger().info(f"{', '.join(sorted(changes))} held until {', '.join(waiting)} "
                                   "are set too (they belong together)")
            return SetParametersResult(successful=True)
        self.pending_params = {}
        self.cfg, self.loc = cfg, Localizer(cfg)
        self.get_logger().info(f"parameters changed ({', '.join(sorted(changes))}): track restarted")
        return SetParametersResult(successful=True)

    def _incomplete_pair(self, changes: dict, error: str) -> list[str]:
        """The names still missing when every change belongs to one group of parameters set together and the
        only fault is that the group is incomplete ([] otherwise: a real error)."""
        if "set together" not in error:
            return []
        for group in PAIRED:
            if set(changes) <= set(group):
                given = set(changes) | set(self.pending_params)
                return [name for name in group if name not in given]
        return []

    # -- inputs -------------------------------------------------------------------------------------
    def _lost_counter(self, key: str) -> SubscriptionEventCallbacks:
        """The middleware's message-lost events of a subscription, counted under `key`."""
        def on_lost(status):
            self.counts[key] += int(status.total_count_change)
        return SubscriptionEventCallbacks(message_lost=on_lost)

    def on_fix(self, msg):
        t0 = time.perf_counter()
        self.counts["fixes_received"] += 1
        try:
            r = fix_from_navsatfix(msg)
        except (AttributeError, TypeError, ValueError):
            self.counts["adapter_errors"] += 1
            return
        self._publish(self.loc.add_fix(r.stamp, r.lat, r.lon, r.alt, r.status, r.sigma_m))
        self._timed(t0)

    def on_bearing(self, msg):
        t0 = time.perf_counter()
        self.counts["bearings_received"] += 1
        try:
            if self.cfg.bearing_encoding == "df_record":
                r = df_from_vector3stamped(msg)
                self.df_gaps.add(r.stamp)
                est = self.loc.add_bearing(r.stamp, r.azimuth_deg, r.quality)
            else:
                r = bearing_from_pose(msg)
                self.df_gaps.add(r.stamp)
                est = self.loc.add_bearing_enu(r.stamp, r.yaw_rad, r.variance_rad2)
        except (AttributeError, TypeError, ValueError):
            self.counts["adapter_errors"] += 1
            return
        self._publish(est)
        self._timed(t0)

    def _timed(self, t0: float):
        dt = time.perf_counter() - t0
        self.callback_s.append(dt)
        self.callback_max_s = max(self.callback_max_s, dt)

    # -- outputs ------------------------------------------------------------------------------------
    def _publish(self, est):
        if est is None:
            return
        T = self.T
        self.pub_pose.publish(build.emitter_pose(T, est))
        self.pub_fix.publish(build.emitter_fix(T, est, self.loc.frame.alt0))
        self.pub_particles.publish(build.particle_array(T, est))
        rays = self.loc.recent_points(self.get_parameter("marker_rays").value)[:, :3]
        ring = ellipse_points((est.east, est.north), est.cov, ELLIPSE_95)
        self.pub_markers.publish(build.markers(T, est, rays, ring))

    def diagnostics(self) -> tuple[int, str, dict]:
        """(level, message, values) of the localizer's state, as published on /diagnostics."""
        loc = self.loc
        values = dict(self.counts)
        values.update(status=loc.status, algorithm=self.cfg.algorithm, bearings_used=loc.bearings_used,
                      points_used=loc.points_used, unknown_quality=loc.unknown_quality,
                      bearings_rejected=sum(v for k, v in loc.rejected.items() if not k.startswith("fix_")),
                      fixes_rejected=sum(v for k, v in loc.rejected.items() if k.startswith("fix_")))
        values.update({f"rejected.{k}": v for k, v in sorted(loc.rejected.items())})
        load = sum(self.callback_s) / self.get_parameter("diagnostics_period_s").value
        if self.callback_s:
            values.update(callback_mean_ms=f"{1e3 * sum(self.callback_s) / len(self.callback_s):.3f}",
                          callback_max_ms=f"{1e3 * self.callback_max_s:.3f}",
                          callbacks_in_period=len(self.callback_s), load_pct=f"{100 * load:.0f}")
        est = loc.estimate
        if est is not None:
            values.update(ess=f"{est.ess:.1f}", update_ms=f"{1e3 * loc.last_update_s:.3f}",
                          east=f"{est.east:.2f}", north=f"{est.north:.2f}", lat=f"{est.lat:.7f}", lon=f"{est.lon:.7f}",
                          ellipse95_major_m=f"{ellipse_axes(est.cov)[0]:.2f}")
        values.update(self._robustness_values())
        if self.pending_params:
            values["parameters_held"] = ", ".join(sorted(self.pending_params)) + " (waiting for the rest of the group)"
        wrong = self._wrong_publishers()
        if wrong:
            values["wrong_encoding"] = "; ".join(wrong)
        level = 0 if est is not None else 1
        if loc.emitter.health.alarm_since is not None:
            level = max(level, 1)  # the cloud no longer explains the newest points: a global check is under way
        if load > _MAX_LOAD:
            level = max(level, 1)
            values["overload"] = (f"input callbacks took {100 * load:.0f} % of the last period: the node cannot keep "
                                  f"up (inputs queue, and past input_queue_depth are lost); fewer particles help")
        values.update(df_stamp_gaps=self.df_gaps.gaps, df_missing_by_stamp=self.df_gaps.missing)
        clock = loc.clock_hint_sentence()
        if clock:
            level = max(level, 1)
            values["clock_offset"] = clock
        lost = self.counts["fixes_lost"] + self.counts["bearings_lost"]
        if lost > self.lost_reported:
            level = max(level, 1)
            values["messages_lost"] = (f"{lost - self.lost_reported} input messages lost by the middleware in the last "
                                       "period (network, or input_queue_depth too small for the load)")
        self.lost_reported = lost
        if wrong:
            level = max(level, 1)
        message = loc.status if not wrong else f"{loc.status}; {wrong[0]}"
        if "overload" in values:
            message += "; the node cannot keep up with its inputs"
        if "messages_lost" in values:
            message += "; input messages are being lost"
        if clock:
            message += "; the DF stamps look offset from the GPS clock"
        return level, message, values

    def _robustness_values(self) -> dict:
        """Self-calibrated noise, modes, the health test and the robustness events, as diagnostic values."""
        loc, values = self.loc, {}
        if self.cfg.calibrate_noise:
            noise = loc.noise_summary()
            values["noise"] = noise_sentence(noise)
            values.update({f"noise.sigma_deg.q{k}": v for k, v in noise["sigma_deg"].items()})
            values.update({"noise.reading_outlier_prob": noise["reading_outlier_prob"],
                           "noise.point_outlier_prob": noise["point_outlier_prob"]})
        values["health.recent_outlier_share"] = f"{loc.emitter.health.share:.2f}"
        est = loc.estimate
        if est is not None:
            values["modes"] = len(est.modes)
            values.update({f"mode.{i + 1}": f"E {e:.1f} N {n:.1f} mass {m:.3f}" for i, (e, n, m) in enumerate(est.modes)})
        values.update({f"events.{k}": v for k, v in sorted(loc.events.items())})
        return values

    def _wrong_publishers(self) -> list[str]:
        """Publishers on our input topics with another message type (DDS never delivers them)."""
        out = []
        expected = ((self.fix_sub.topic_name, FIX_TYPE), (self.bearing_sub.topic_name, INPUT_TYPES[self.cfg.bearing_encoding]))
        for topic, want in expected:
            for info in self.get_publishers_info_by_topic(topic):
                if info.topic_type != want:
                    out.append(f"{topic} has a {info.topic_type} publisher ({info.node_name}); expected {want}")
        return out

    def publish_diagnostics(self):
        level, message, values = self.diagnostics()
        now = self.get_clock().now().nanoseconds * 1e-9
        self.pub_diag.publish(build.diagnostic_array(self.T, now, DIAG_NAME, level, message, values))
        self.callback_s, self.callback_max_s = [], 0.0

    def on_reset(self, request, response):
        self.loc.reset()
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
        response.success = True
        response.message = "track and datum dropped; the next confirmed fix sets the datum"
        self.get_logger().info(response.message)
        return response


def main(argv=None) -> int:
    return run_node(NODE_NAME, LocalizerNode, rclpy.spin, (ConfigError,), argv)


if __name__ == "__main__":
    sys.exit(main())
