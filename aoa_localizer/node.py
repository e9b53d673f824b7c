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
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from msgs_adapters import build
from msgs_adapters.fields import (
    bearing_from_pose,
    df_from_vector3stamped,
    fix_from_navsatfix,
)

from .config import GROUPS, MAX_PARTICLES, ConfigError, LocalizerConfig
from .crlb import ELLIPSE_95, ellipse_axes
from .localizer import Localizer
from .noise import sentence as noise_sentence
from .ros_main import run_node

NODE_NAME = "aoa_localizer"
PAIRED = (("datum_lat", "datum_lon"), ("prior_east", "prior_north", "prior_sigma_m"))  # set together
_MAX_LOAD = 0.8  # share of wall time in input callbacks above which /diagnostics warns
DIAG_NAME = "aoa_localizer: localizer"
INPUT_TYPES = {"df_record": "geometry_msgs/msg/Vector3Stamped", "pose": "geometry_msgs/msg/PoseWithCovarianceStamped"}
FIX_TYPE = "sensor_msgs/msg/NavSatFix"

DESCRIPTIONS = {
    "algorithm": "filter: afsa (AFSA-PF), sir (bootstrap), espf (evolution sampling), gfapf (gravitation field), "
                 "upfde (UKF proposal + differential evolution), upf, pfde, agapf (adaptive genetic)",
    "num_particles": "number of particles N",
    "seed": "filter seed; unset: random. The same seed reproduces a run",
    "bearing_sigma_deg": "bearing noise sigma per reading (deg) for sigma_model constant",
    "sigma_model": "constant, or quality: sigma linear between sigma_q40_deg and sigma_q100_deg",
    "sigma_q100_deg": "bearing sigma at quality 100 (deg), sigma_model quality",
    "sigma_q40_deg": "bearing sigma at quality 40 (deg), sigma_model quality",
    "likelihood": "mixture (Gaussian + uniform outliers) or gaussian (the paper's)",
    "outlier_prob": "share of wild bearings the mixture likelihood allows for",
    "process_noise_m": "random walk per step (m) for sir and afsa.variant paper",
    "quality_min": "readings with a lower DF quality are dropped",
    "point_weighting": "corrected bearing of a point: paper (eqs. 19-21), inverse_variance or equal",
    "obs_max_duration_s": "longest span of one observation point (s)",
    "obs_max_distance_m": "longest distance covered by one observation point (m)",
    "obs_max_readings": "most readings in one observation point",
    "df_correlation": "correlation of the readings at one point (1: n readings count as one)",
    "point_gate_sigma": "drop readings this many sigmas from the point's median (0: off)",
    "init_method": "start: global (search of the robust posterior over all points) or triangulation (the paper's)",
    "init_bearings": "observation points before a start is tried",
    "init_min_crossing_deg": "steepest crossing needed to start (deg)",
    "init_min_support": "triangulation start: share of points that must agree with a starting crossing",
    "init_max_points": "points kept while waiting for geometry",
    "prior_east": "Gaussian prior mean east (m, map); with prior_north and prior_sigma_m replaces triangulation",
    "prior_north": "Gaussian prior mean north (m, map)",
    "prior_sigma_m": "Gaussian prior sigma (m)",
    "datum_lat": "latitude of the map origin (deg); unset: the first valid fix",
    "datum_lon": "longitude of the map origin (deg); unset: the first valid fix",
    "datum_alt": "altitude of the map origin (m); unset: the first valid fix's",
    "gps_max_gap_s": "longest fix gap a bearing may be interpolated across (s)",
    "max_stamp_jump_s": "a stamp this far ahead of its stream is refused, not adopted; a clock step is followed after 3 agreeing stamps (s)",
    "df_time_offset_s": "added to every DF stamp to put it on the GPS clock (a receiver stamping 0.5 s late: -0.5)",
    "gps_sigma_m": "GPS position noise (m), added to each bearing's variance by range; 0: each fix's own position_covariance",
    "bearing_encoding": "df_record (Vector3Stamped: azimuth deg, quality) or pose (PoseWithCovarianceStamped yaw)",
    "resampling": "systematic, stratified, residual or multinomial",
    "ess_threshold": "resample when the effective sample size falls below this share of N",
    "history_points": "observation points the MCMC moves' posterior keeps",
    "calibrate_noise": "learn the receiver's sigma per quality band and the outlier rate from the data",
    "global_safety": "health test, global searches, independence moves, re-starts and the emitter-moved test",
    "health_window": "recent points whose outlier share is tested against the outlier rate",
    "health_p_value": "binomial tail below which the recent outlier share raises the alarm",
    "restart_log_odds": "re-start from a global mode whose log posterior beats the cloud's best by this (nats)",
    "moved_min_points": "disagreeing recent points needed before the emitter-moved test",
    "moved_log_odds": "log likelihood ratio (nats) both old and recent points must show to declare the emitter moved",
    "afsa.variant": "mcmc (consistent, default) or paper (the fish school as printed)",
    "afsa.visual": "visual range: metres (paper) or standard deviations of the school (mcmc)",
    "afsa.step": "fish step (m), paper variant",
    "afsa.crowd": "crowd factor delta, paper variant",
    "afsa.try_number": "prey tries per fish and round, paper variant",
    "afsa.max_iterations": "school rounds (paper) or MCMC sweeps (mcmc)",
    "afsa.tolerance": "stop the paper school when the mean log-objective change is smaller",
    "espf.sbx_lambda": "ESPF: distribution index of the simulated binary crossover (larger: children nearer their parents)",
    "gfapf.attraction": "GFA-PF: attraction weight M towards the central dust",
    "gfapf.rotation_max": "GFA-PF: largest rotation factor f of the repulsion",
    "gfapf.iterations": "GFA-PF: gravitation iterations D per measurement",
    "gfapf.attract_min": "GFA-PF: no attraction closer than this to the centre (scale units)",
    "gfapf.repel_max": "GFA-PF: no repulsion farther than this from the centre (scale units)",
    "gfapf.scale": "GFA-PF: absolute (state units) or spread (standard deviations of the cloud)",
    "de.f1": "UPF-DE/PF-DE: scale F1 of the base vector in V = F1 X_r1 + F2 (X_r2 - X_r3)",
    "de.f2": "UPF-DE/PF-DE: scale F2 of the difference vector",
    "de.cr": "UPF-DE/PF-DE: binomial crossover rate",
    "de.generations": "UPF-DE/PF-DE: DE generations G per measurement",
    "agapf.pc1": "AGA-PF: crossover probability below the average fitness",
    "agapf.pc2": "AGA-PF: crossover probability floor for the fittest",
    "agapf.pm1": "AGA-PF: mutation probability below the average fitness",
    "agapf.pm2": "AGA-PF: mutation probability floor for the fittest",
    "agapf.a": "AGA-PF: steepness A of the adaptive curves",
}
# Node-only parameters (not engine settings).
NODE_PARAMS = {
    "input_queue_depth": (200, "subscription queue depth for gps/fix and df/bearing"),
    "marker_rays": (20, "bearing rays drawn in emitter/markers (the latest observation points)"),
    "diagnostics_period_s": (1.0, "period of /diagnostics (s)"),
}
RANGES = {
    "num_particles": (2, MAX_PARTICLES), "quality_min": (0.0, 100.0), "outlier_prob": (0.0, 0.999),
    "df_correlation": (0.0, 1.0), "init_min_support": (0.0, 1.0), "ess_threshold": (0.0, 1.0),
    "obs_max_readings": (1, 100_000), "init_bearings": (2, 100_000), "history_points": (1, 100_000),
    "health_window": (3, 1000), "moved_min_points": (3, 100_000), "health_p_value": (0.0, 1.0),
}


def _descriptor(name: str, default) -> ParameterDescriptor:
    d = ParameterDescriptor(description=DESCRIPTIONS.get(name, NODE_PARAMS.get(name, (None, ""))[1]))
    if default is None:
        d.dynamic_typing = True  # unset until given; then any number
    if name in RANGES:
        lo, hi = RANGES[name]
        if isinstance(lo, int):
            d.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
    return d


def engine_parameter_names() -> list[str]:
    names = [f.name for f in fields(LocalizerConfig) if f.name not in GROUPS]
    return names + [f"{group}.{f.name}" for group, cls in GROUPS.items() for f in fields(cls)]


ENGINE_PARAMS = frozenset(engine_parameter_names())


class LocalizerNode(Node):
    """Runs the Localizer on the node's inputs and publishes what it makes."""

    def __init__(self):
        super().__init__(NODE_NAME)
        defaults = LocalizerConfig().to_dict()
        for name in engine_parameter_names():
            self.declare_parameter(name, defaults[name], _descriptor(name, defaults[name]))
        for name, (default, _) in NODE_PARAMS.items():
            self.declare_parameter(name, default, _descriptor(name, default))
        self.cfg = self._config_from({})  # raises ConfigError: the caller refuses to start
        self.loc = Localizer(self.cfg)
        self.T = build.rclpy_types()
        self.counts = {"fixes_received": 0, "bearings_received": 0, "adapter_errors": 0}
        self.callback_s: list[float] = []
        self.pending_params: dict = {}  # the first parameters of a group set together, held until it is complete
        self.callback_max_s = 0.0

        depth = self.get_parameter("input_queue_depth").value
        sensor = QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                            durability=DurabilityPolicy.VOLATILE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.fix_sub = self.create_subscription(self.T.NavSatFix, "gps/fix", self.on_fix, sensor)
        bearing_type = self.T.Vector3Stamped if self.cfg.bearing_encoding == "df_record" else self.T.PoseWithCovarianceStamped
        self.bearing_sub = self.create_subscription(bearing_type, "df/bearing", self.on_bearing, sensor)
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
        values = {name: self.get_parameter(name).value for name in engine_parameter_names()}
        values.update(changes)
        return LocalizerConfig.from_dict(values)

    def on_set_parameters(self, params) -> SetParametersResult:
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
        if cfg.bearing_encoding != self.cfg.bearing_encoding:
            return SetParametersResult(successful=False, reason="bearing_encoding is fixed at start; restart the node")
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
                est = self.loc.add_bearing(r.stamp, r.azimuth_deg, r.quality)
            else:
                r = bearing_from_pose(msg)
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
        rays = self.loc.filter.model.history.data[-self.get_parameter("marker_rays").value:, :3]
        self.pub_markers.publish(build.markers(T, est, rays, ELLIPSE_95))

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
        if wrong:
            level = max(level, 1)
        message = loc.status if not wrong else f"{loc.status}; {wrong[0]}"
        if "overload" in values:
            message += "; the node cannot keep up with its inputs"
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
