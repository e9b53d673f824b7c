"""Message conversions on both flavours: rclpy classes and rosbags-deserialised dataclasses."""
import math

import numpy as np
import pytest
from conftest import open_point
from rclpy.serialization import serialize_message

from aoa_localizer import Localizer, LocalizerConfig
from aoa_localizer.engine.crlb import ELLIPSE_95, ellipse_points
from aoa_localizer.engine.types import BearingPoseInput, Estimate, Input
from msgs_adapters import build
from msgs_adapters.bag import typestore
from msgs_adapters.fields import (
    bearing_from_pose,
    df_from_vector3stamped,
    df_record,
    df_scan,
    diagnostics_values,
    estimate_from_pose,
    fix_from_navsatfix,
)

RCLPY = build.rclpy_types()
TS = typestore()
ROSBAGS = build.rosbags_types(TS)


def via_bag(msg, type_name):
    """An rclpy message as a bag holds it and rosbags reads it back."""
    return TS.deserialize_cdr(bytes(serialize_message(msg)), type_name)


def flavours(msg, type_name):
    return [msg, via_bag(msg, type_name)]


@pytest.fixture
def estimate():
    return Estimate(stamp=12.25, east=1200.5, north=-800.25, lat=39.1072, lon=117.2139,
                    cov=np.array([[4.0, 1.5], [1.5, 9.0]]), bearings_used=30, points_used=6, ess=77.0,
                    algorithm="afsa", particles=np.array([[1.0, 2.0], [3.0, 4.0]]), weights=np.array([0.5, 0.5]))


@pytest.mark.parametrize("T", [RCLPY, ROSBAGS], ids=["rclpy", "rosbags"])
def test_navsatfix_and_df_record_read_the_same_from_either_class(T):
    fix = build.navsatfix(T, 10.5, 39.1, 117.2, 5.0, status=-1)
    df = build.df_record(T, 10.75, 359.5, 88.0, 433.92e6)
    assert fix_from_navsatfix(fix)[:5] == (10.5, 39.1, 117.2, 5.0, -1)
    assert math.isnan(fix_from_navsatfix(fix).sigma_m)  # covariance type unknown
    assert df_from_vector3stamped(df)[:4] == (10.75, 359.5, 88.0, 433.92e6)
    known = build.navsatfix(T, 10.5, 39.1, 117.2, 5.0, covariance=np.diag([9.0, 16.0, 25.0]), covariance_type=2)
    assert fix_from_navsatfix(known).sigma_m == pytest.approx(math.sqrt(12.5))


def test_inputs_survive_the_trip_through_a_bag():
    fix = build.navsatfix(RCLPY, 1.000000001, -33.9, -70.6, 520.0)
    back = fix_from_navsatfix(via_bag(fix, "sensor_msgs/msg/NavSatFix"))
    assert back[:5] == pytest.approx(fix_from_navsatfix(fix)[:5]) and math.isnan(back.sigma_m)
    df = build.df_record(RCLPY, 2.5, 12.0, float("nan"))
    back = df_from_vector3stamped(via_bag(df, "geometry_msgs/msg/Vector3Stamped"))
    assert back.azimuth_deg == 12.0 and math.isnan(back.quality)


@pytest.mark.parametrize("yaw", [0.3, -2.9, math.pi / 2])
def test_pose_encoding_bearing_round_trip(yaw):
    msg = build.pose_bearing(RCLPY, 3.0, yaw, 0.0004)
    for m in flavours(msg, "geometry_msgs/msg/PoseWithCovarianceStamped"):
        r = bearing_from_pose(m)
        assert r.stamp == 3.0 and r.yaw_rad == pytest.approx(yaw) and r.variance_rad2 == pytest.approx(0.0004)


@pytest.mark.parametrize("yaw", [0.3, -2.9, math.pi / 2])
def test_a_pose_bearing_is_read_as_a_df_record_with_its_own_sigma(yaw):
    """The node hands either encoding to the engine by one call: the pose's yaw as an azimuth from north, its
    variance as the reading's sigma (a variance of 0: not known), no quality or frequency."""
    r = df_record(build.pose_bearing(RCLPY, 3.0, yaw, 0.0004), "pose")
    assert r.stamp == 3.0 and r.azimuth_deg == pytest.approx(90.0 - math.degrees(yaw))
    assert r.sigma_deg == pytest.approx(math.degrees(0.02)) and math.isnan(r.quality) and math.isnan(r.frequency_hz)
    assert math.isnan(df_record(build.pose_bearing(RCLPY, 3.0, yaw, 0.0), "pose").sigma_deg)
    df = build.df_record(RCLPY, 10.75, 359.5, 88.0, 433.92e6)
    assert df_record(df, "df_record") == df_from_vector3stamped(df)


@pytest.mark.parametrize("yaw, variance, used", [(0.3, 0.0004, True), (-2.9, 1e-6, True), (math.pi / 2, 0.0, True),
                                                 (0.5, math.nan, True), (1.0, -1.0, False), (1.0, math.inf, False)])
def test_the_nodes_pose_path_and_add_bearing_enu_make_the_same_reading(yaw, variance, used):
    """The pose's yaw and variance are turned into an azimuth and a sigma in the adapter (the node) and in
    add_bearing_enu (the API, a bag's bearing_pose): bit for bit the same reading, so one pose gives one answer.
    A variance of NaN or 0 stands for the configured sigma; a negative or infinite one is add_bearing's bad sigma,
    refused by both paths (a decoy with an infinite variance was once used at the configured sigma)."""
    r = df_record(build.pose_bearing(RCLPY, 1.0, yaw, variance), "pose")
    readings, refused = [], []
    for feed in (lambda loc: loc.add_bearing(r.stamp, r.azimuth_deg, r.quality, sigma_deg=r.sigma_deg),
                 lambda loc: loc.feed(Input("bearing_pose", BearingPoseInput(1.0, yaw, variance)))):
        loc = Localizer(LocalizerConfig(seed=1, datum_lat=39.1, datum_lon=117.2))
        loc.add_fix(0.0, 39.1, 117.2)
        loc.add_fix(2.0, 39.1, 117.2)
        feed(loc)
        readings.append(open_point(loc))
        refused.append(loc.view().rejected.get("bad_sigma", 0))
        loc.close()
    assert len(readings[0]) == int(used) and readings[0] == readings[1]
    assert refused == [0, 0] if used else refused == [1, 1]


def quaternion(yaw: float, scale: float = 1.0):
    return RCLPY.Quaternion(x=0.0, y=0.0, z=scale * math.sin(yaw / 2), w=scale * math.cos(yaw / 2))


@pytest.mark.parametrize("scale", [1.0, 1.02, 0.97, 1.04])
def test_a_nearly_unit_quaternion_is_normalised_before_its_yaw_is_read(scale):
    """A quaternion a little off unit length (rounding, a float32 publisher) gives its true yaw: read raw, x1.02
    once moved the estimate 25 m."""
    for yaw in (0.0, math.pi / 2, 2.5, -1.2):
        msg = build.pose_bearing(RCLPY, 1.0, 0.0, 0.0004)
        msg.pose.pose.orientation = quaternion(yaw, scale)
        for m in flavours(msg, "geometry_msgs/msg/PoseWithCovarianceStamped"):
            assert bearing_from_pose(m).yaw_rad == pytest.approx(yaw, abs=1e-12)


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 2 * math.sin(0.5), 2 * math.cos(0.5)),
                               (0.0, 0.0, 0.5 * math.sin(0.5), 0.5 * math.cos(0.5)), (0.0, 0.0, math.inf, 1.0),
                               (0.0, 0.0, 1e200, 1.0), (math.nan, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.1)])
def test_a_zero_far_from_unit_or_non_finite_quaternion_gives_no_yaw_and_the_reading_is_refused(q):
    """A quaternion whose squared norm is off one by more than tf2's 0.1, or zero, or not finite, has no yaw: the
    pose bearing is refused as a bad azimuth, live and from a bag (once: x2 read -37 deg, a zero one 90 deg)."""
    msg = build.pose_bearing(RCLPY, 1.0, 0.0, 0.0004)
    msg.pose.pose.orientation = RCLPY.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])
    for m in flavours(msg, "geometry_msgs/msg/PoseWithCovarianceStamped"):
        p = bearing_from_pose(m)
        assert math.isnan(p.yaw_rad)
        loc = Localizer(LocalizerConfig(seed=1, datum_lat=39.1, datum_lon=117.2))
        loc.add_fix(0.0, 39.1, 117.2)
        loc.feed(Input("bearing_pose", BearingPoseInput(p.stamp, p.yaw_rad, p.variance_rad2)))
        r = df_record(m, "pose")
        loc.add_bearing(r.stamp, r.azimuth_deg, r.quality, sigma_deg=r.sigma_deg)
        assert loc.view().rejected.get("bad_azimuth") == 2 and not open_point(loc)
        loc.close()


def test_emitter_pose_carries_the_estimate_and_its_covariance(estimate):
    msg = build.emitter_pose(RCLPY, estimate)
    assert msg.header.frame_id == "map"
    for m in flavours(msg, "geometry_msgs/msg/PoseWithCovarianceStamped"):
        stamp, east, north, cov = estimate_from_pose(m)
        assert (stamp, east, north) == (12.25, 1200.5, -800.25)
        assert np.array(cov) == pytest.approx(estimate.cov)
        # z and the orientation are not estimated: a large variance, never 0 ("known exactly" to ROS consumers)
        full = np.array(m.pose.covariance).reshape(6, 6)
        assert np.all(np.diag(full)[2:] == build.UNESTIMATED_VARIANCE) and not full[2:, :2].any()


def test_emitter_fix_is_lat_lon_with_an_approximated_enu_covariance(estimate):
    msg = build.emitter_fix(RCLPY, estimate, alt=5.0)
    for m in flavours(msg, "sensor_msgs/msg/NavSatFix"):
        r = fix_from_navsatfix(m)
        assert (r.lat, r.lon, r.alt) == (39.1072, 117.2139, 5.0)
        assert m.position_covariance_type == 1
        assert np.array(m.position_covariance).reshape(3, 3)[:2, :2] == pytest.approx(estimate.cov)
        # the altitude is not estimated: unknown, as emitter/pose's z (0 said it was exact; issue 67, item 4)
        assert m.position_covariance[8] == build.UNESTIMATED_VARIANCE and not np.array(m.position_covariance)[
            [2, 5, 6, 7]].any()


def test_particles_become_poses(estimate):
    msg = build.particle_array(RCLPY, estimate)
    for m in flavours(msg, "geometry_msgs/msg/PoseArray"):
        assert [(p.position.x, p.position.y) for p in m.poses] == [(1.0, 2.0), (3.0, 4.0)]


def test_markers_hold_the_estimate_a_closed_95_percent_ellipse_and_the_rays(estimate):
    rays = np.array([[0.0, 0.0, 0.5], [100.0, 0.0, 1.0]])
    msg = build.markers(
        RCLPY, estimate, rays, ellipse_points((estimate.east, estimate.north), estimate.cov, ELLIPSE_95)
    )
    for m in flavours(msg, "visualization_msgs/msg/MarkerArray"):
        sphere, ellipse, lines = m.markers
        assert (sphere.pose.position.x, sphere.pose.position.y) == (1200.5, -800.25)
        ring = np.array([(p.x, p.y) for p in ellipse.points])
        assert ring[0] == pytest.approx(ring[-1])
        # Shoelace area against pi a b of the 95 % ellipse (64 segments: within 1 %).
        area = 0.5 * abs(np.dot(ring[:-1, 0], ring[1:, 1]) - np.dot(ring[1:, 0], ring[:-1, 1]))
        assert area == pytest.approx(math.pi * ELLIPSE_95 * math.sqrt(np.linalg.det(estimate.cov)), rel=0.01)
        assert len(lines.points) == 4 and (lines.points[0].x, lines.points[0].y) == (0.0, 0.0)
        direction = math.atan2(lines.points[3].y - lines.points[2].y, lines.points[3].x - lines.points[2].x)
        assert direction == pytest.approx(1.0)


def test_diagnostics_round_trip():
    msg = build.diagnostic_array(
        RCLPY, 5.0, "aoa_localizer: localizer", 1, "waiting", {"bearings_used": 12, "ess": 3.5}
    )
    for m in flavours(msg, "diagnostic_msgs/msg/DiagnosticArray"):
        d = diagnostics_values(m)["aoa_localizer: localizer"]
        assert d == {"bearings_used": "12", "ess": "3.5", "level": "1", "message": "waiting"}


@pytest.mark.parametrize("types", [RCLPY, ROSBAGS], ids=["rclpy", "rosbags"])
def test_a_scan_is_one_record_per_point_at_its_stamp_live_and_from_a_bag(types):
    """Issue 69: a receiver's channels read at one stamp as one sensor_msgs/PointCloud2 (docs/interface.md)."""
    msg = build.df_scan(types, 1000.25, [10.0, 200.5, 359.0], [80.0, 20.0, 55.0], [433.92e6, 446e6, 0.0])
    back = via_bag(msg, "sensor_msgs/msg/PointCloud2") if types is RCLPY else TS.deserialize_cdr(
        TS.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"), "sensor_msgs/msg/PointCloud2")
    for m in (msg, back):
        got = df_scan(m)
        assert [tuple(r)[:4] for r in got] == [(1000.25, 10.0, 80.0, 433.92e6), (1000.25, 200.5, 20.0, 446e6),
                                               (1000.25, 359.0, 55.0, 0.0)]
        assert all(math.isnan(r.sigma_deg) for r in got)
    only = df_scan(build.df_scan(types, 5.0, [1.0, 2.0], sigma_deg=[0.5, 3.0]))  # the optional fields left out
    assert [(r.azimuth_deg, r.frequency_hz, r.sigma_deg) for r in only] == [(1.0, 0.0, 0.5), (2.0, 0.0, 3.0)]
    assert all(math.isnan(r.quality) for r in only) and df_scan(build.df_scan(types, 5.0, [])) == []


def _cloud(fields, data, width, height=1, point_step=12, row_step=None, bigendian=False):
    T = ROSBAGS
    return T.PointCloud2(header=build.header(T, 7.5, "df"), height=height, width=width,
                         fields=[T.PointField(name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields],
                         is_bigendian=bigendian, point_step=point_step,
                         row_step=width * point_step if row_step is None else row_step,
                         data=np.frombuffer(data, np.uint8).copy(), is_dense=True)


def test_a_scan_is_read_by_field_name_type_offset_and_byte_order_and_a_bad_layout_is_refused():
    """Another receiver's cloud: float32 fields in its own order, big-endian, rows of two points padded to 32
    bytes, an extra field; each bad layout is a ValueError (the node counts it as an adapter error)."""
    rows = [[(7.0, 300.0, 1.5), (5.0, 45.0, 2.5)], [(9.0, 90.0, 0.5), (8.0, 180.0, 1.0)]]  # quality, azimuth, x
    data = b"".join(b"".join(np.array(p, ">f4").tobytes() for p in row) + bytes(8) for row in rows)
    fields = [("quality", 0, 7, 1), ("azimuth_deg", 4, 7, 1), ("x", 8, 7, 1)]
    got = df_scan(_cloud(fields, data, 2, height=2, row_step=32, bigendian=True))
    assert [(r.stamp, r.azimuth_deg, r.quality) for r in got] == [(7.5, 300.0, 7.0), (7.5, 45.0, 5.0),
                                                                   (7.5, 90.0, 9.0), (7.5, 180.0, 8.0)]
    good = np.array([1.0, 2.0, 3.0], "<f4").tobytes()
    bad = {"no azimuth": _cloud([("quality", 0, 7, 1)], good, 1),
           "short data": _cloud([("azimuth_deg", 0, 7, 1)], good, 2),
           "field past its point": _cloud([("azimuth_deg", 10, 7, 1)], good, 1),
           "unknown type": _cloud([("azimuth_deg", 0, 42, 1)], good, 1),
           "a field of two": _cloud([("azimuth_deg", 0, 7, 2)], good, 1),
           "no step": _cloud([("azimuth_deg", 0, 7, 1)], good, 1, point_step=0),
           "a million points": _cloud([("azimuth_deg", 0, 7, 1)], good, 1_000_000)}
    for why, msg in bad.items():
        with pytest.raises(ValueError):
            df_scan(msg)
            pytest.fail(why)


def test_the_simulated_vehicle_publishes_each_stations_readings_of_one_stamp_as_one_scan():
    from aoa_localizer.ros.sim_vehicle import scans

    events = [(0.0, "", "fix", "f0"), (0.1, "", "bearing", "a"), (0.1, "", "bearing", "b"), (0.1, "car2", "bearing",
              "c"), (0.2, "", "bearing", "d"), (0.2, "", "fix", "f1"), (0.2, "", "bearing", "e")]
    assert list(scans(iter(events))) == [(0.0, "", "fix", "f0"), (0.1, "", "scan", ["a", "b"]),
                                         (0.1, "car2", "scan", ["c"]), (0.2, "", "scan", ["d"]),
                                         (0.2, "", "fix", "f1"), (0.2, "", "scan", ["e"])]
