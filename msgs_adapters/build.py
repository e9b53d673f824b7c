"""Engine records -> messages, by field name: the caller passes the message classes it uses
(rosbags' typestore classes to write bags, rclpy's to publish), so one function serves both.
The outputs of the node (pose, fix, particles, markers, diagnostics) are built with rclpy's classes."""
from __future__ import annotations

import array
import math
import zlib
from types import SimpleNamespace

import numpy as np

from .fields import seconds_to_stamp


def rosbags_types(typestore) -> SimpleNamespace:
    """The message classes of a rosbags typestore under short names."""
    t = typestore.types
    return SimpleNamespace(
        Time=t["builtin_interfaces/msg/Time"], Header=t["std_msgs/msg/Header"],
        NavSatFix=t["sensor_msgs/msg/NavSatFix"], NavSatStatus=t["sensor_msgs/msg/NavSatStatus"],
        Vector3Stamped=t["geometry_msgs/msg/Vector3Stamped"], Vector3=t["geometry_msgs/msg/Vector3"],
        PointStamped=t["geometry_msgs/msg/PointStamped"], Point=t["geometry_msgs/msg/Point"],
        Quaternion=t["geometry_msgs/msg/Quaternion"], Pose=t["geometry_msgs/msg/Pose"],
        PoseWithCovariance=t["geometry_msgs/msg/PoseWithCovariance"],
        PoseWithCovarianceStamped=t["geometry_msgs/msg/PoseWithCovarianceStamped"],
        PointCloud2=t["sensor_msgs/msg/PointCloud2"], PointField=t["sensor_msgs/msg/PointField"], numpy_bytes=True,
    )


def rclpy_types() -> SimpleNamespace:
    """rclpy's message classes under the same short names, plus the node's output types."""
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import (
        Point,
        PointStamped,
        Pose,
        PoseArray,
        PoseStamped,
        PoseWithCovariance,
        PoseWithCovarianceStamped,
        Quaternion,
        Twist,
        TwistWithCovariance,
        TwistWithCovarianceStamped,
        Vector3,
        Vector3Stamped,
    )
    from nav_msgs.msg import MapMetaData, OccupancyGrid, Path
    from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus, PointCloud2, PointField
    from std_msgs.msg import ColorRGBA, Header, String
    from visualization_msgs.msg import Marker, MarkerArray

    return SimpleNamespace(**{c.__name__: c for c in (
        Time, Header, NavSatFix, NavSatStatus, Vector3Stamped, Vector3, PointStamped, Point, Pose, PoseArray,
        PoseWithCovariance, PoseWithCovarianceStamped, Quaternion, ColorRGBA, Marker, MarkerArray,
        DiagnosticArray, DiagnosticStatus, KeyValue, Path, PoseStamped, Imu, String, OccupancyGrid, MapMetaData,
        PointCloud2, PointField, Twist, TwistWithCovariance, TwistWithCovarianceStamped)})


def header(T, stamp: float, frame_id: str):
    sec, nanosec = seconds_to_stamp(stamp)
    return T.Header(stamp=T.Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def navsatfix(T, stamp: float, lat: float, lon: float, alt: float, status: int = 0,
              frame_id: str = "gps", covariance=None, covariance_type: int = 0):
    """sensor_msgs/NavSatFix (service 1 = GPS)."""
    cov = np.zeros(9) if covariance is None else np.asarray(covariance, float).reshape(9)
    return T.NavSatFix(header=header(T, stamp, frame_id), status=T.NavSatStatus(status=status, service=1),
                       latitude=float(lat), longitude=float(lon), altitude=float(alt), position_covariance=cov,
                       position_covariance_type=covariance_type)


def df_record(T, stamp: float, azimuth_deg: float, quality: float, frequency_hz: float = 0.0,
              frame_id: str = "df_antenna"):
    """geometry_msgs/Vector3Stamped DF record."""
    return T.Vector3Stamped(header=header(T, stamp, frame_id),
                            vector=T.Vector3(x=float(azimuth_deg), y=float(quality), z=float(frequency_hz)))


def df_scan(T, stamp: float, azimuth_deg, quality=None, frequency_hz=None, sigma_deg=None,
            frame_id: str = "df_antenna"):
    """sensor_msgs/PointCloud2 DF scan (one point per channel read at `stamp`): FLOAT64 fields azimuth_deg and, when
    given, quality, frequency_hz and sigma_deg (docs/interface.md, "A scan as one message")."""
    given = {"azimuth_deg": azimuth_deg, "quality": quality, "frequency_hz": frequency_hz, "sigma_deg": sigma_deg}
    columns = {k: np.asarray(v, float).reshape(-1) for k, v in given.items() if v is not None}
    n = len(columns["azimuth_deg"])
    fields = [T.PointField(name=k, offset=8 * i, datatype=8, count=1) for i, k in enumerate(columns)]
    data = np.column_stack(list(columns.values())).astype("<f8").tobytes() if n else b""
    return T.PointCloud2(header=header(T, stamp, frame_id), height=1, width=n, fields=fields, is_bigendian=False,
                         point_step=8 * len(columns), row_step=8 * len(columns) * n, data=_bytes_for(T, data),
                         is_dense=True)


def _bytes_for(T, data: bytes):
    """A message's uint8[] as its classes take it without a check per byte: rosbags' as a numpy array, rclpy's as
    an array('B')."""
    return np.frombuffer(data, np.uint8).copy() if getattr(T, "numpy_bytes", False) else array.array("B", data)


def pose_bearing(T, stamp: float, yaw_rad: float, variance_rad2: float, frame_id: str = "df_antenna"):
    """geometry_msgs/PoseWithCovarianceStamped bearing (the `pose` encoding): yaw in the orientation,
    its variance in covariance[35]."""
    cov = np.zeros(36)
    cov[35] = variance_rad2
    q = T.Quaternion(x=0.0, y=0.0, z=math.sin(yaw_rad / 2), w=math.cos(yaw_rad / 2))
    return T.PoseWithCovarianceStamped(
        header=header(T, stamp, frame_id),
        pose=T.PoseWithCovariance(pose=T.Pose(position=T.Point(x=0.0, y=0.0, z=0.0), orientation=q), covariance=cov),
    )


def point_stamped(T, stamp: float, x: float, y: float, z: float = 0.0, frame_id: str = "map"):
    """geometry_msgs/PointStamped."""
    return T.PointStamped(header=header(T, stamp, frame_id), point=T.Point(x=float(x), y=float(y), z=float(z)))


# The variance of what emitter/pose does not estimate (z, roll, pitch, yaw): large, the convention for "unknown"
# (robot_localization's and nav2's consumers read 0 as "known exactly")
UNESTIMATED_VARIANCE = 1e9


def emitter_pose(T, est, frame_id: str = "map"):
    """emitter/pose: x east, y north, the 2x2 covariance in the x/y block; z and the orientation are not estimated
    (UNESTIMATED_VARIANCE on their diagonal, 0 off it)."""
    cov = np.zeros(36)
    cov[[14, 21, 28, 35]] = UNESTIMATED_VARIANCE
    cov[[0, 1, 6, 7]] = np.asarray(est.cov, float).reshape(4)
    pose = T.Pose(position=T.Point(x=est.east, y=est.north, z=0.0), orientation=T.Quaternion(w=1.0))
    return T.PoseWithCovarianceStamped(
        header=header(T, est.stamp, frame_id), pose=T.PoseWithCovariance(pose=pose, covariance=cov)
    )


def emitter_velocity(T, est, frame_id: str = "map"):
    """emitter/velocity: linear x east, y north (m/s) over both motion models (a standing transmitter's is zero), the
    2x2 covariance in the x/y block; z and the angular part are not estimated (UNESTIMATED_VARIANCE)."""
    cov = np.zeros(36)
    cov[[14, 21, 28, 35]] = UNESTIMATED_VARIANCE
    cov[[0, 1, 6, 7]] = np.asarray(est.velocity_cov, float).reshape(4)
    linear = T.Vector3(x=float(est.velocity[0]), y=float(est.velocity[1]), z=0.0)
    return T.TwistWithCovarianceStamped(header=header(T, est.stamp, frame_id), twist=T.TwistWithCovariance(
        twist=T.Twist(linear=linear, angular=T.Vector3()), covariance=cov))


def emitter_fix(T, est, alt: float, frame_id: str = "emitter"):
    """emitter/fix: lat/lon with the covariance in east/north at the emitter (m^2), COVARIANCE_TYPE_APPROXIMATED;
    the altitude is not estimated (UNESTIMATED_VARIANCE, as emitter/pose's z: 0 would say it is exact)."""
    cov = np.zeros(9)
    ground = getattr(est, "ground_cov", None)
    cov[[0, 1, 3, 4]] = np.asarray(est.cov if ground is None else ground, float).reshape(4)
    cov[8] = UNESTIMATED_VARIANCE
    return navsatfix(T, est.stamp, est.lat, est.lon, alt, status=0, frame_id=frame_id, covariance=cov,
                     covariance_type=1)


def datum_fix(T, stamp: float, lat: float, lon: float, alt: float, frame_id: str = "map"):
    """emitter/datum: the WGS84 position of the map frame's origin (frame_id the map frame), no covariance."""
    return navsatfix(T, stamp, lat, lon, alt, status=0, frame_id=frame_id)


def vehicle_path(T, stamp: float, track, frame_id: str = "map"):
    """vehicle/path: the accepted GPS fixes, rows (stamp, east, north) in the map frame, oldest first."""
    poses = [
        T.PoseStamped(header=header(T, t, frame_id),
                      pose=T.Pose(position=T.Point(x=float(e), y=float(n), z=0.0), orientation=T.Quaternion(w=1.0)))
        for t, e, n in track
    ]
    return T.Path(header=header(T, stamp, frame_id), poses=poses)


def occupancy_grid(T, stamp: float, east0: float, north0: float, resolution: float, values, frame_id: str = "map"):
    """emitter/posterior: `values` (rows going north, columns east, 0-100) as an OccupancyGrid whose cell (0, 0) has
    its lower-left corner at (east0, north0) in the map frame."""
    rows, cols = values.shape
    info = T.MapMetaData(map_load_time=header(T, stamp, frame_id).stamp, resolution=float(resolution), width=cols,
                         height=rows, origin=T.Pose(position=T.Point(x=float(east0), y=float(north0), z=0.0),
                                                    orientation=T.Quaternion(w=1.0)))
    return T.OccupancyGrid(header=header(T, stamp, frame_id), info=info, data=values.astype("int8").ravel().tolist())


def goal_pose(T, stamp: float, vehicle: tuple[float, float], goal: tuple[float, float], frame_id: str = "map"):
    """emitter/next_goal: the goal (east, north in the map frame), facing the way from `vehicle` to it."""
    yaw = math.atan2(goal[1] - vehicle[1], goal[0] - vehicle[0])
    orientation = T.Quaternion(z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))
    return T.PoseStamped(header=header(T, stamp, frame_id),
                         pose=T.Pose(position=T.Point(x=float(goal[0]), y=float(goal[1]), z=0.0),
                                     orientation=orientation))


def goal_arrow(T, stamp: float, vehicle: tuple[float, float], goal: tuple[float, float], channel: str,
               frame_id: str = "map"):
    """emitter/next_goal_marker: an arrow from the vehicle to the goal (a frequency channel's in its colour)."""
    own = channel_colour(channel)
    r, g, b = own or (0.1, 0.8, 0.3)
    return T.Marker(header=header(T, stamp, frame_id), ns=("" if own is None else f"{channel}/") + "next_goal", id=0,
                    type=0, action=0, scale=T.Vector3(x=3.0, y=8.0, z=8.0), color=T.ColorRGBA(r=r, g=g, b=b, a=1.0),
                    pose=T.Pose(orientation=T.Quaternion(w=1.0)),
                    points=[T.Point(x=float(vehicle[0]), y=float(vehicle[1]), z=0.0),
                            T.Point(x=float(goal[0]), y=float(goal[1]), z=0.0)])


def particle_array(T, est, frame_id: str = "map"):
    """emitter/particles: one pose per particle."""
    poses = [
        T.Pose(position=T.Point(x=float(x), y=float(y), z=0.0), orientation=T.Quaternion(w=1.0))
        for x, y in est.particles
    ]
    return T.PoseArray(header=header(T, est.stamp, frame_id), poses=poses)


# Each frequency channel's estimate and ellipse in its own colour (the default channel keeps red and amber).
PALETTE = ((0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16), (0.58, 0.4, 0.74),
           (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5), (0.74, 0.74, 0.13), (0.09, 0.75, 0.81))


def channel_colour(channel: str) -> tuple[float, float, float] | None:
    """A channel's colour, stable across runs (from its id); None for the default channel."""
    if channel == "default":
        return None
    return PALETTE[zlib.crc32(channel.encode()) % len(PALETTE)]


def markers(T, est, rays, ring, frame_id: str = "map"):
    """emitter/markers: the estimate (sphere), its 95 % ellipse (line strip through `ring`, (P, 2) east/north
    points), the bearing rays (line list; rays: (M, 3) antenna east, north and ENU bearing of the latest points).
    A frequency channel's markers have its id as namespace prefix and its colour (channel_colour)."""
    h = header(T, est.stamp, frame_id)
    colour = lambda r, g, b: T.ColorRGBA(r=r, g=g, b=b, a=1.0)  # noqa: E731
    own = channel_colour(est.channel)
    prefix = "" if own is None else f"{est.channel}/"
    sphere = T.Marker(
        header=h,
        ns=prefix + "estimate",
        id=0,
        type=2,
        action=0,
        scale=T.Vector3(x=4.0, y=4.0, z=4.0),
        color=colour(*(own or (1.0, 0.1, 0.1))),
        pose=T.Pose(position=T.Point(x=est.east, y=est.north, z=0.0), orientation=T.Quaternion(w=1.0)),
    )
    ring = [T.Point(x=float(x), y=float(y), z=0.0) for x, y in ring]
    ellipse = T.Marker(
        header=h,
        ns=prefix + "ellipse95",
        id=1,
        type=4,
        action=0,
        scale=T.Vector3(x=1.0),
        color=colour(*(own or (1.0, 0.8, 0.0))),
        pose=T.Pose(orientation=T.Quaternion(w=1.0)),
        points=ring,
    )
    segments = []
    for e, n, theta in rays:
        length = 1.2 * math.hypot(est.east - e, est.north - n) + 50.0
        segments += [
            T.Point(x=float(e), y=float(n), z=0.0),
            T.Point(x=float(e + length * math.cos(theta)), y=float(n + length * math.sin(theta)), z=0.0),
        ]
    ray_marker = T.Marker(
        header=h,
        ns=prefix + "bearings",
        id=2,
        type=5,
        action=0,
        scale=T.Vector3(x=0.5),
        color=colour(0.2, 0.6, 1.0),
        pose=T.Pose(orientation=T.Quaternion(w=1.0)),
        points=segments,
    )
    return T.MarkerArray(markers=[sphere, ellipse, ray_marker])


def diagnostic_array(T, stamp: float, name: str, level: int, message: str, values: dict, hardware_id: str = "",
                     more: list | None = None):
    """/diagnostics with one status, and one more per (name, level, message, values) of `more`; values become
    KeyValue strings."""
    statuses = [
        T.DiagnosticStatus(
            level=bytes([lv]),
            name=nm,
            message=msg,
            hardware_id=hardware_id,
            values=[T.KeyValue(key=str(k), value=str(v)) for k, v in vals.items()],
        )
        for nm, lv, msg, vals in [(name, level, message, values)] + list(more or [])
    ]
    return T.DiagnosticArray(header=header(T, stamp, ""), status=statuses)
