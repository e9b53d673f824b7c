"""Launch tests: the real node, vehicle, launcher and replay as processes over Fast DDS, each test in its
own ROS domain; children are killed by process group whether the test passes or not."""
import functools
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import rclpy
from conftest import DATUM, ros_env
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.qos import QoSProfile
from std_srvs.srv import Trigger

from aoa_localizer.engine.geodesy import LocalFrame
from aoa_localizer.simulation.scenarios import SCENARIOS, simulate
from msgs_adapters import build
from msgs_adapters.bag import read_bag
from msgs_adapters.fields import diagnostics_values, estimate_from_pose

ROOT = Path(__file__).resolve().parent.parent
T = build.rclpy_types()

pytestmark = [pytest.mark.ros, pytest.mark.slow]  # real processes over Fast DDS


@contextmanager
def client(domain, name="test_client", namespace=None):
    """An rclpy node in its own context in `domain`."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node(name, context=ctx, namespace=namespace)
    executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def spin_until(executor, predicate, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        executor.spin_once(timeout_sec=0.05)
    return predicate()


def call(executor, node, srv_type, name, request, timeout=10.0, resend_s=2.0, sent: list | None = None):
    """One service call; the request is sent again every `resend_s` until a response comes. Fast DDS may report
    the service available before the server has matched the client's response reader, and then drops the
    response (ros2/rmw_fastrtps#390: the server waits 100 ms for the match); every service the node offers gives
    the same answer when asked twice (a parameter set is counted each time: `sent` gets how many were sent)."""
    cli = node.create_client(srv_type, name)
    assert cli.wait_for_service(timeout_sec=timeout), f"no service {name}"
    futures = [cli.call_async(request)]
    end = time.monotonic() + timeout
    while not any(f.done() for f in futures) and time.monotonic() < end:
        if not spin_until(executor, lambda: any(f.done() for f in futures), min(resend_s, end - time.monotonic())):
            futures.append(cli.call_async(request))
    answered = [f for f in futures if f.done()]
    assert answered, f"no response from {name} to {len(futures)} requests in {timeout} s"
    if sent is not None:
        sent.append(len(futures))
    return answered[0].result()


def launch(args, timeout=180):
    return subprocess.run([sys.executable, "-m", "aoa_localizer.launch", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def no_process_with(marker: str) -> bool:
    out = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout
    return marker not in out


def test_vehicle_and_node_converge_and_the_launcher_leaves_no_process(tmp_path, domain):
    marker = f"marker_rays:={40 + domain}"  # a node argument no other test uses
    res = launch(["--scenario", "seed", "--speedup", 80, "--seed", 2, "--domain-id", domain,
                  "-p", marker.replace(":=", "="), "--result", tmp_path / "r.json", "--keep-logs"])
    assert res.returncode == 0, res.stdout + res.stderr
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["converged"] and result["error_m"] < 10.0
    assert "error against the simulated truth" in res.stdout
    # east and north say what they are measured from (issue 53, item 6)
    assert f"from the node's datum {result['datum'][0]:.7f}, {result['datum'][1]:.7f}" in res.stdout
    assert no_process_with(marker)
    logdir = Path(re.search(r"logs in (\S+);", res.stdout).group(1))
    assert "Traceback" not in (logdir / "aoa_localizer.log").read_text()  # nor the check worker's, at Ctrl-C


def test_the_two_car_scenario_plays_both_cars_into_one_node_and_its_bag_replays(tmp_path, domain):
    """`--scenario pair`: the vehicle plays car1 and car2 on their own topics, the launcher gives the node
    `stations: [car1, car2]`; the ellipse is the fused one (each car alone: 21-23 m long, tests/test_stations.py).
    The sample bag replays live the same way, its stations read from its topic names (no --scenario)."""
    # the bag at 20x (8 s): as fast as allowed, a node starved of CPU beside other jobs once lost 24 of its 204
    # bearings in the middleware's queue before its first estimate (issue 69: a node that keeps up)
    for args in (["--scenario", "pair", "--speedup", 80], ["--bag", ROOT / "bags/pair", "--rate", 20]):
        res = launch([*args, "--seed", 1, "--domain-id", domain, "--result", tmp_path / "r.json"])
        assert res.returncode == 0, res.stdout + res.stderr
        result = json.loads((tmp_path / "r.json").read_text())
        assert result["converged"] and result["error_m"] < 10.0 and result["ellipse95_m"][0] < 15.0, result


def test_a_vehicle_with_its_array_mounted_at_an_offset_is_read_as_mounted(tmp_path, domain):
    """`--vehicle-param mount_offset_deg=30`: the vehicle publishes azimuths from its forward axis and the launcher
    tells the node so (read as true-north azimuths they would point 30-120 deg away)."""
    res = launch(["--scenario", "seed", "--speedup", 80, "--seed", 4, "--domain-id", domain,
                  "--vehicle-param", "mount_offset_deg=30", "--result", tmp_path / "r.json"])
    assert res.returncode == 0, res.stdout + res.stderr
    assert json.loads((tmp_path / "r.json").read_text())["error_m"] < 10.0
    # a converged run leaves no aoa_launch_* folder behind (issue 53, part 4) unless --keep-logs
    assert "logs removed" in res.stdout and not Path(re.search(r"logs in (\S+);", res.stdout).group(1)).exists()


def test_a_launcher_timeout_says_where_the_run_stood(domain):
    """`--timeout`: exit 2 with the last status (what was received and used, the estimate so far), not a bare
    "timeout"."""
    res = launch(["--scenario", "seed", "--speedup", 10, "--timeout", 6, "--domain-id", domain])
    assert res.returncode == 2 and "timeout after 6 s; last status [" in res.stderr, res.stdout + res.stderr
    assert "bearings received" in res.stderr.split("timeout after")[1], res.stderr


def test_pose_encoding_and_a_vehicle_driving_to_the_goal_end_to_end(tmp_path, domain):
    """The pose encoding end to end, with the vehicle following emitter/next_goal (`drive=goal`): it starts on the
    straight road (north -200 m) and leaves it for the emitter (1200, 800) once the node has an estimate. Where it
    goes first is the goal's choice: across the early bearings, which may be south of the road (once in six runs
    it went to -301 m)."""
    res = launch(["--scenario", "straight", "--speedup", 40, "--seed", 3, "--domain-id", domain,
                  "-p", "bearing_encoding=pose", "--vehicle-param", "bearing_encoding=pose",
                  "--vehicle-param", "drive=goal", "--record", tmp_path / "bag", "--result", tmp_path / "r.json"])
    assert res.returncode == 0, res.stdout + res.stderr
    assert json.loads((tmp_path / "r.json").read_text())["error_m"] < 10.0
    frame = LocalFrame(*SCENARIOS["straight"].datum)
    norths = [frame.to_enu(ev.record.lat, ev.record.lon)[1] for ev in read_bag(tmp_path / "bag") if ev.kind == "fix"]
    assert norths[0] == pytest.approx(-200.0, abs=1.0) and max(norths) > 300.0


@contextmanager
def running_launcher(domain, marker):
    """`launch --scenario urban` at 2x, running for 5 s (marked by a node argument); killed if still running."""
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "aoa_localizer.launch",
            "--scenario",
            "urban",
            "--speedup",
            "2",
            "--domain-id",
            str(domain),
            "-p",
            marker.replace(":=", "="),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        time.sleep(5)
        assert p.poll() is None
        yield p
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)


def test_sigterm_to_the_launcher_stops_everything(domain):
    marker = f"marker_rays:={150 + domain}"
    with running_launcher(domain, marker) as p:
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=30)
        assert p.returncode == 2 and "stopped by SIGTERM" in err
        assert no_process_with(marker)


def test_a_bag_is_scored_in_one_frame_with_its_scenarios_settings(tmp_path, domain):
    """The node's map is at its first confirmed fix (3 m GPS noise on urban), the bag's truth at the scenario's
    datum: the launcher compares them in one frame, so its error is the lat/lon error."""
    res = launch(["--bag", ROOT / "bags/urban", "--scenario", "urban", "--rate", 2, "--seed", 2, "--domain-id", domain,
                  "--result", tmp_path / "r.json"])
    assert res.returncode == 0, res.stdout + res.stderr
    got = json.loads((tmp_path / "r.json").read_text())
    east, north = LocalFrame(*DATUM).to_enu(got["lat"], got["lon"])
    assert got["error_m"] == pytest.approx(math.hypot(east - 1200.0, north - 800.0), abs=0.05)
    assert got["error_m"] < 5.0  # with urban's receiver settings (--scenario): 0.9 m in a trial run


def test_sample_bag_through_the_live_node_gives_the_offline_estimate(tmp_path, domain):
    res = launch(
        ["--bag", ROOT / "bags/seed", "--rate", 2, "--seed", 5, "--domain-id", domain, "--result", tmp_path / "r.json"]
    )
    assert res.returncode == 0, res.stdout + res.stderr
    live = json.loads((tmp_path / "r.json").read_text())
    off = subprocess.run(
        [
            sys.executable,
            "-m",
            "aoa_localizer.replay",
            ROOT / "bags/seed",
            "--offline",
            "--output",
            tmp_path / "off.jsonl",
            "--seed",
            "5",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert off.returncode == 0, off.stderr
    lines = [json.loads(line) for line in (tmp_path / "off.jsonl").read_text().splitlines()][1:]  # after the header
    assert lines[-1]["end_of_data"]  # offline ends with the end-of-data global check, which a live node never sees
    last = [d for d in lines if not d["end_of_data"]][-1]
    # Same engine, same data: the same place well inside the ellipse. Not to the last digit at --rate 2: while a
    # global check runs (tens of ms) the node's two input queues fill and are served out of the bag's log order,
    # which moves observation-point boundaries (docs/ros.md; at --rate 0.5 it matched to the last digit).
    assert np.hypot(live["east"] - last["east"], live["north"] - last["north"]) < 0.5
    # The ellipses' size (the product of the semi-axes): here it is nearly a circle, so its two axes are each a
    # hundred particles' ill-conditioned split of it (0.70 x 0.74 m, or 0.58 x 0.86 m, for the same area). The live
    # and the offline run are two Monte Carlo runs of it: over 12 offline filter seeds the size spreads by 10 % (0.39 to
    # 0.57), and one seed's over another's exceeds 1.28 one time in twenty (at most 1.47), so they agree within 1.5x.
    sizes = [np.sqrt(np.linalg.det(np.array(c))) for c in (live["cov"], last["cov"])]
    assert 1 / 1.5 < sizes[0] / sizes[1] < 1.5, sizes


def _drive_publishers(node, executor):
    """The client's NavSatFix and DF publishers, made once per node: a second pair made for a later drive is matched
    anew, and its first fixes could reach the node after the bearings they pair with (counted as gps_gap)."""
    pubs = getattr(node, "_drive_publishers", None)
    if pubs is None:
        pubs = (node.create_publisher(T.NavSatFix, "gps/fix", QoSProfile(depth=100)),
                node.create_publisher(T.Vector3Stamped, "df/bearing", QoSProfile(depth=100)))
        assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs), 10)
        spin_until(executor, lambda: False, 1.0)  # both ends of the match settled: nothing lost at the start
        node._drive_publishers = pubs
    return pubs


def _publish_drive(node, executor, emitter, seconds=60.0, speed=20.0, df_hz=10.0, start_east=0.0, t0=1000.0):
    """An outside client's vehicle driving east from (start_east, 0) from stamp t0: NavSatFix and DF records per
    docs/interface.md, paced 2 ms apart."""
    frame = LocalFrame(*DATUM)
    pub_fix, pub_df = _drive_publishers(node, executor)
    rng = np.random.default_rng(0)
    for k in range(int(seconds * df_hz) + 1):
        t = k / df_hz
        if k % int(df_hz) == 0:
            lat, lon, alt = frame.to_geodetic(start_east + speed * t, 0.0)
            pub_fix.publish(build.navsatfix(T, t0 + t, float(lat), float(lon), float(alt)))
        az = math.degrees(math.atan2(emitter[0] - start_east - speed * t, emitter[1])) % 360
        pub_df.publish(build.df_record(T, t0 + t, az + rng.normal(0, 1.0), 90.0))
        executor.spin_once(timeout_sec=0.002)


def test_an_outside_client_gets_pose_fix_posterior_and_goal(spawn, domain):
    """emitter/pose and emitter/fix near the truth; emitter/velocity, a standing transmitter's (about zero, in the
    map frame, stamped as the pose); emitter/posterior with the estimate in its most probable cells;
    emitter/next_goal within goal_radius_m of the vehicle's last place (1200, 0), its arrow from there."""
    node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "seed:=1", "-p", "goal_radius_m:=300.0"], domain)
    emitter = (600.0, 400.0)
    with client(domain) as (node, executor):
        got = {}
        latched = QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(T.PoseWithCovarianceStamped, "emitter/pose", lambda m: got.update(pose=m), latched)
        node.create_subscription(T.NavSatFix, "emitter/fix", lambda m: got.update(fix=m), 10)
        node.create_subscription(T.TwistWithCovarianceStamped, "emitter/velocity",
                                 lambda m: got.update(velocity=m), latched)
        node.create_subscription(T.OccupancyGrid, "emitter/posterior", lambda m: got.update(grid=m), 1)
        node.create_subscription(T.PoseStamped, "emitter/next_goal", lambda m: got.update(goal=m), 1)
        node.create_subscription(T.Marker, "emitter/next_goal_marker", lambda m: got.update(arrow=m), 1)
        diag: dict = {}
        node.create_subscription(T.DiagnosticArray, "/diagnostics", lambda m: diag.update(
            diagnostics_values(m).get("aoa_localizer: localizer", {})), 10)
        _publish_drive(node, executor, emitter)
        assert spin_until(executor, lambda: "pose" in got and "fix" in got, 10), open(node_p.log_path).read()
        spin_until(executor, lambda: False, 2.0)  # the last points
        _, east, north, cov = estimate_from_pose(got["pose"])
        # emitter/posterior, while listened to: the estimate in its most probable cells, in the map frame
        assert spin_until(executor, lambda: "grid" in got, 5)
        # their cost named in /diagnostics (issue 51, item 3: the overload warning blamed the filter)
        assert spin_until(executor, lambda: "posterior_grids_ms" in diag, 5), json.dumps(diag)
        grid, info = got["grid"], got["grid"].info
        values = np.array(grid.data, np.int8).reshape(info.height, info.width)
        row = int((north - info.origin.position.y) / info.resolution)
        col = int((east - info.origin.position.x) / info.resolution)
        assert grid.header.frame_id == "map" and values[row, col] >= 50 and values.max() == 100
        assert got["pose"].header.frame_id == "map"
        assert math.hypot(east - emitter[0], north - emitter[1]) < 15.0
        e, n = LocalFrame(*DATUM).to_enu(got["fix"].latitude, got["fix"].longitude)
        assert math.hypot(e - emitter[0], n - emitter[1]) < 15.0
        assert got["fix"].position_covariance_type == 1
        # published with each pose: a velocity may reach this client after its pose (or the pose after it)
        assert spin_until(executor, lambda: "velocity" in got
                          and got["velocity"].header.stamp == got["pose"].header.stamp, 5)
        velocity = got["velocity"]
        assert velocity.header.frame_id == "map"
        assert math.hypot(velocity.twist.twist.linear.x, velocity.twist.twist.linear.y) < 1.0  # it stands
        assert velocity.twist.covariance[0] >= 0.0 and velocity.twist.covariance[35] == 1e9
        got.pop("goal", None)
        assert spin_until(executor, lambda: "goal" in got and "arrow" in got, 5)  # refreshed once a second
        goal, arrow = got["goal"].pose.position, got["arrow"].points
        assert (arrow[0].x, arrow[0].y) == pytest.approx((1200.0, 0.0), abs=0.5)  # the vehicle's last fix
        assert got["goal"].header.frame_id == "map"
        assert math.hypot(goal.x - arrow[0].x, goal.y - arrow[0].y) <= 300.0 + 1e-6
        assert (arrow[1].x, arrow[1].y) == pytest.approx((goal.x, goal.y))
    assert node_p.poll() is None


def test_frames_datum_path_and_stale_inputs_in_a_namespace(spawn, domain):
    """map_frame and the emitter's frame in the messages; the datum published latched and kept across a parameter
    change; the vehicle's path in the map frame; the status named after the node; WARN once the inputs stop."""
    args = ["-r", "__ns:=/van1", "-p", "map_frame:=site", "-p", "input_reliability:=reliable",
            "-p", "diagnostics_period_s:=0.3", "-p", "stale_after_s:=1.5", "-p", "hardware_id:=kraken-7"]
    node_p = spawn(["aoa_localizer.node", "--ros-args", *args], domain)
    emitter = (600.0, 400.0)
    frame = LocalFrame(*DATUM)
    with client(domain, namespace="/van1") as (node, executor):
        got: dict = {"datum": [], "status": {}}
        latched = QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(T.NavSatFix, "emitter/datum", got["datum"].append, latched)
        node.create_subscription(T.PoseWithCovarianceStamped, "emitter/pose", lambda m: got.update(pose=m), latched)
        node.create_subscription(T.NavSatFix, "emitter/fix", lambda m: got.update(fix=m), 10)
        node.create_subscription(T.Path, "vehicle/path", lambda m: got.update(path=m), 10)

        def on_diag(m):
            got["status"] = {st.name: st for st in m.status}

        node.create_subscription(T.DiagnosticArray, "/diagnostics", on_diag, 10)
        _publish_drive(node, executor, emitter, seconds=30.0)
        assert spin_until(executor, lambda: {"pose", "fix", "path"} <= set(got) and got["datum"], 10), open(
            node_p.log_path
        ).read()
        spin_until(executor, lambda: len(got["path"].poses) == 31, 5)
        datum = got["datum"][0]
        lat0, lon0, alt0 = frame.to_geodetic(0.0, 0.0)  # the first fix: the datum when none is configured
        assert datum.header.frame_id == "site" and (datum.latitude, datum.longitude) == pytest.approx((lat0, lon0))
        # stamped in measurement time, as every output (the node's wall clock once: 5 days from a bag's stamps)
        fix_stamps = [p.header.stamp.sec + 1e-9 * p.header.stamp.nanosec for p in got["path"].poses]
        assert fix_stamps[0] <= datum.header.stamp.sec + 1e-9 * datum.header.stamp.nanosec <= fix_stamps[-1]
        assert got["pose"].header.frame_id == "site" and got["fix"].header.frame_id == "emitter"
        path = got["path"]
        assert path.header.frame_id == "site" and len(path.poses) == 31  # a fix a second for 30 s
        assert [p.pose.position.x for p in path.poses] == pytest.approx([20.0 * k for k in range(31)], abs=0.01)

        changed = SetParameters.Request(parameters=[Parameter(
            name="num_particles", value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=150))])
        assert call(executor, node, SetParameters, "/van1/aoa_localizer/set_parameters", changed).results[0].successful
        got.pop("pose")
        _publish_drive(node, executor, emitter, seconds=30.0, start_east=-300.0)  # a first fix 300 m west
        assert spin_until(executor, lambda: "pose" in got, 10)
        spin_until(executor, lambda: False, 1.0)
        assert len(got["datum"]) == 1  # the map did not move with the new track's first fix
        _, east, north, _ = estimate_from_pose(got["pose"])
        assert math.hypot(east - emitter[0], north - emitter[1]) < 15.0  # in the same frame as before

        name = "van1/aoa_localizer: localizer"
        assert spin_until(executor, lambda: "df_stale" in diagnostics_values(T.DiagnosticArray(
            status=list(got["status"].values()))).get(name, {}), 10), list(got["status"])
        status = got["status"][name]
        assert status.hardware_id == "kraken-7" and status.level == b"\x01"
        assert "no DF reading for" in status.message and "no valid GPS fix for" in status.message
    assert node_p.poll() is None


def test_an_imu_heading_and_its_variance_turn_relative_bearings_in_the_node(spawn, domain):
    """`heading_source imu`: a vehicle driving east past the emitter publishes its IMU yaw (with a variance) and
    azimuths from its nose; the node takes every heading and turns the bearings by it into an estimate."""
    spawn(["aoa_localizer.node", "--ros-args", "-p", "bearing_reference:=vehicle", "-p", "heading_source:=imu",
           "-p", "diagnostics_period_s:=0.5", "-p", "input_reliability:=reliable"], domain)
    frame = LocalFrame(*DATUM)
    emitter = np.array([150.0, 300.0])
    with client(domain) as (node, executor):
        diag = {}
        node.create_subscription(T.DiagnosticArray, "/diagnostics",
                                 lambda m: diag.update(diagnostics_values(m).get("aoa_localizer: localizer", {})), 10)
        pubs = {topic: node.create_publisher(kind, topic, QoSProfile(depth=500))
                for topic, kind in (("gps/fix", T.NavSatFix), ("df/bearing", T.Vector3Stamped), ("heading/imu", T.Imu))}
        assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs.values()), 10)
        spin_until(executor, lambda: False, 1.0)
        for k in range(61):  # 10 m/s east for 30 s, every half second
            t = 100.0 + 0.5 * k
            east = 10.0 * (t - 100.0)
            imu = T.Imu(header=build.header(T, t, "imu"))
            imu.orientation.w, imu.orientation_covariance[8] = 1.0, 1e-4  # yaw 0 (east), known to 0.01 rad
            pubs["heading/imu"].publish(imu)
            if k % 2 == 0:
                lat, lon, _ = frame.to_geodetic(east, 0.0)
                pubs["gps/fix"].publish(build.navsatfix(T, t, float(lat), float(lon), 5.0))
            true_azimuth = math.degrees(math.atan2(emitter[0] - east, emitter[1]))
            pubs["df/bearing"].publish(build.df_record(T, t + 0.25, (true_azimuth - 90.0) % 360.0, 90.0))
            spin_until(executor, lambda: False, 0.02)
        assert spin_until(executor, lambda: int(diag.get("bearings_used", 0)) >= 40, 15), json.dumps(diag)
        assert not [k for k in diag if "heading" in k and k.startswith("rejected.")], json.dumps(diag)


def test_bad_messages_leave_the_node_running_and_are_counted(spawn, domain):
    # Every message must arrive: a best-effort subscription (the default) may drop one under load, so this test
    # asks for reliable ones. (Its last failure, 2 of 4 fixes, was the node dying in the log bridge: see rosout.)
    node_p = spawn(
        ["aoa_localizer.node", "--ros-args", "-p", "diagnostics_period_s:=0.5", "-p", "input_reliability:=reliable"],
        domain,
    )
    frame = LocalFrame(*DATUM)
    with client(domain) as (node, executor), client(domain, "wrong_type_publisher") as (other, _):
        diag = {}
        node.create_subscription(
            T.DiagnosticArray,
            "/diagnostics",
            lambda m: diag.update(diagnostics_values(m).get("aoa_localizer: localizer", {})),
            10,
        )
        pub_fix = node.create_publisher(T.NavSatFix, "gps/fix", QoSProfile(depth=100))
        pub_df = node.create_publisher(T.Vector3Stamped, "df/bearing", QoSProfile(depth=100))
        other.create_publisher(T.PoseWithCovarianceStamped, "df/bearing", 10)  # a wrong encoding on the topic
        assert spin_until(executor, lambda: pub_fix.get_subscription_count() and pub_df.get_subscription_count(), 10)
        spin_until(executor, lambda: False, 1.0)  # both ends of the match settled: nothing lost at the start
        lat, lon, _ = frame.to_geodetic(0.0, 0.0)
        sequence = [
            (pub_fix, build.navsatfix(T, 100.0, float(lat), float(lon), 5.0)),
            (pub_fix, build.navsatfix(T, 101.0, float(lat), float(lon), 5.0, status=-1)),  # no fix
            (pub_df, build.df_record(T, 100.5, float("nan"), 90.0)),  # NaN azimuth
            (pub_df, build.df_record(T, 100.6, 45.0, 90.0)),
            (pub_df, build.df_record(T, 100.4, 45.0, 90.0)),  # stamp going backwards
            (pub_df, build.df_record(T, 100.7, 45.0, 250.0)),  # quality out of range
            (pub_fix, build.navsatfix(T, 102.0, float("nan"), float(lon), 5.0)),  # NaN position
            (pub_fix, build.navsatfix(T, 102.5, float(lat), float(lon), 5.0)),
        ]
        for pub, msg in sequence:
            pub.publish(msg)
            spin_until(executor, lambda: False, 0.05)
        # The counts of received messages belong in the wait: the last message (a good fix) changes no rejection
        # counter, so a snapshot taken between the rejections and that fix showed fixes_received 3 (the flake).
        expected = {
            "rejected.bad_azimuth": "1",
            "rejected.fix_no_fix": "1",
            "rejected.bearing_out_of_order": "1",
            "rejected.bad_quality": "1",
            "rejected.fix_bad_position": "1",
            "bearings_received": "4",
            "fixes_received": "4",
        }
        assert spin_until(
            executor, lambda: all(diag.get(k) == v for k, v in expected.items()) and "wrong_encoding" in diag, 10
        ), json.dumps(diag)
        assert "PoseWithCovarianceStamped" in diag["wrong_encoding"] and diag["level"] == "1"
        assert "-p bearing_encoding:=pose" in diag["wrong_encoding"]  # the hint names the fix
        assert diag["bearings_received"] == "4" and diag["fixes_received"] == "4"
        assert node_p.poll() is None

        reset = call(executor, node, Trigger, "/aoa_localizer/reset", Trigger.Request())
        assert reset.success
        dropped = call(executor, node, Trigger, "/aoa_localizer/reset_datum", Trigger.Request())
        assert dropped.success and "datum dropped" in dropped.message  # it came from a fix, not the config
        bad = SetParameters.Request(
            parameters=[
                Parameter(
                    name="algorithm", value=ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="kalman")
                )
            ]
        )
        result = call(executor, node, SetParameters, "/aoa_localizer/set_parameters", bad).results[0]
        assert not result.successful and "algorithm must be one of" in result.reason
        good = SetParameters.Request(
            parameters=[
                Parameter(
                    name="num_particles", value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=200)
                )
            ]
        )
        assert call(executor, node, SetParameters, "/aoa_localizer/set_parameters", good).results[0].successful
    assert node_p.poll() is None


def test_node_refuses_to_start_with_an_invalid_parameter(tmp_path, domain):
    params = tmp_path / "p.yaml"
    params.write_text("aoa_localizer:\n  ros__parameters:\n    datum_lat: 39.1\n")
    res = subprocess.run(
        [sys.executable, "-m", "aoa_localizer.node", "--ros-args", "--params-file", str(params)],
        env=ros_env(domain),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2 and "datum_lat and datum_lon are set together" in res.stderr


@pytest.mark.parametrize("args, words", [
    (["--params-file", "PARAMS"], "num_particle: unknown parameter; did you mean num_particles?"),
    (["-p", "nosuch:=1"], "nosuch: unknown parameter"),
    (["-p", "diagnostics_period_s:=0.0"], "diagnostics_period_s must be a finite number in [0.01, 3600], got 0.0"),
    (["-p", "num_particles:=0"], "num_particles must be an integer in [2, 100000], got 0"),
    (["-p", "stations:=[car1,2car]"], "stations must be a list of names"),
    (["-p", "stations:=[car1,car1]"], "stations lists car1 more than once"),
    (["-p", "stations:=[car1]", "-p", "fixed_stations:=[mast]"], "fixed_stations mast not in stations"),
    (["-p", "stations:=[mast]", "-p", "fixed_stations:=[mast]", "-p", "mast.position:=[39.1]"],
     "mast.position must be [lat, lon] or [lat, lon, alt]"),
    (["-p", "stations:=[mast]", "-p", "fixed_stations:=[mast]", "-p", "mast.position:=[0.0,0.0]"],
     "mast.position [0.0, 0.0] is not a usable position"),
    (["-p", "stations:=[car1]", "-p", "car1.position:=[39.1,117.2]"], "car1.position: unknown parameter"),
    (["-p", "scheduling:=off"], "scheduling must be one of auto, realtime, reproducible (YAML reads on/off"),
    (["-p", "num_particles:=abc"], "num_particles must be an integer in [2, 100000]"),
])
def test_the_node_refuses_unknown_names_and_bad_node_only_values_at_start(tmp_path, domain, args, words):
    """ROS-package issue: misspelt names ran with defaults, diagnostics_period_s:=0 flooded /diagnostics and -1
    crashed the node. Each is refused at start, exit 2, with the reason in the engine's words (an out-of-range
    value too, which rclpy's range check would word as its own)."""
    params = tmp_path / "p.yaml"
    params.write_text("aoa_localizer:\n  ros__parameters:\n    num_particle: 50\n")
    args = [str(params) if a == "PARAMS" else a for a in args]
    res = subprocess.run([sys.executable, "-m", "aoa_localizer.node", "--ros-args", *args], env=ros_env(domain),
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and words in res.stderr, res.stderr
    assert "Traceback" not in res.stderr


@pytest.mark.parametrize("args, words", [
    (["-p", "gps_dropout_prob:=2.0"], "gps_dropout_prob must be a finite number in [0, 1) or unset, got 2.0"),
    (["-p", "wild_share:=abc"], "wild_share must be a finite number in [0, 1] or unset, got 'abc'"),
    (["-p", "scenari:=urban"], "scenari: unknown parameter; did you mean scenario?"),
    (["-p", "emitters:=[4.0e8,1.0]"], "emitters needs frequency, east, north triples"),
    (["-p", "drive:=goal", "-p", "scenario:=urban"], "drive goal: urban drives without stopping"),
])
def test_the_vehicle_refuses_bad_parameters_at_start(domain, args, words):
    """ROS-package issue: gps_dropout_prob 2 was accepted, wild_share abc gave a numpy traceback."""
    res = subprocess.run([sys.executable, "-m", "aoa_localizer.sim_vehicle", "--ros-args", *args],
                         env=ros_env(domain), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and words in res.stderr, res.stderr
    assert "Traceback" not in res.stderr


def test_sim_truth_and_emitter_pose_share_one_map_frame(spawn, domain):
    """Issue 67, item 3: sim/truth was in the scenario's datum and emitter/pose in the node's first fix's, both
    `map`: a client comparing them saw 5.2 m where the error was 1.3 m. The vehicle publishes its truths again in the
    node's frame once emitter/datum says where it is; sim/datum then names that frame."""
    node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "seed:=1"], domain)
    vehicle = spawn(["aoa_localizer.sim_vehicle", "--ros-args", "-p", "speedup:=40.0", "-p", "data_seed:=2",
                     "-p", "wait_for_subscribers:=1"], domain)
    with client(domain) as (node, executor):
        got: dict = {}
        latched = QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        for topic, kind in (("sim/truth", T.PointStamped), ("sim/datum", T.NavSatFix),
                            ("emitter/datum", T.NavSatFix), ("emitter/pose", T.PoseWithCovarianceStamped)):
            node.create_subscription(kind, topic, functools.partial(got.__setitem__, topic), latched)

        def one_frame() -> bool:
            if len(got) < 4:
                return False
            same = (got["sim/datum"].latitude, got["sim/datum"].longitude) == pytest.approx(
                (got["emitter/datum"].latitude, got["emitter/datum"].longitude), abs=1e-9)
            return same and vehicle.poll() is not None  # the drive is played
        assert spin_until(executor, one_frame, 120), open(vehicle.log_path).read() + open(node_p.log_path).read()
        spin_until(executor, lambda: False, 2.0)  # the last points' estimate
    _, east, north, cov = estimate_from_pose(got["emitter/pose"])
    truth = got["sim/truth"].point
    # the truth in the node's frame: the error the launcher reports, inside the pose's own ellipse scale
    data = simulate("seed", 2)
    lat, lon, _ = data.frame.to_geodetic(*data.emitter_enu)
    node_frame = LocalFrame(got["emitter/datum"].latitude, got["emitter/datum"].longitude)
    assert (truth.x, truth.y) == pytest.approx(tuple(map(float, node_frame.to_enu(lat, lon))), abs=0.01)
    assert math.hypot(east - truth.x, north - truth.y) < 3.0 * math.sqrt(np.trace(np.array(cov))) + 1.0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_the_vehicle_stops_cleanly_mid_play(spawn, domain, sig):
    """ROS-package issue: SIGINT or SIGTERM mid-play printed an RCLError traceback in 4 of 5 tries."""
    p = spawn(["aoa_localizer.sim_vehicle", "--ros-args", "-p", "wait_for_subscribers:=0",
               "-p", "start_timeout_s:=0.0", "-p", "speedup:=5.0"], domain)
    deadline = time.monotonic() + 30
    while "t = 0 s" not in open(p.log_path).read() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(0.5)  # inside the play loop
    p.send_signal(sig)
    assert p.wait(15) == 0
    log = open(p.log_path).read()
    assert "playing seed" in log and "Traceback" not in log and "RCLError" not in log, log


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_the_node_and_live_replay_stop_cleanly_on_a_signal(spawn, domain, sig):
    """ROS-package issue: clean shutdown without tracebacks on SIGINT and SIGTERM in every program (live replay
    died in an RCLError: rclpy's handler invalidated the context under a publish)."""
    node_p = spawn(["aoa_localizer.node"], domain)
    player = spawn(["aoa_localizer.replay", str(ROOT / "bags/seed"), "--rate", "1", "--wait", "5"], domain)
    with client(domain) as (node, executor):
        read_only = SetParameters.Request(parameters=[Parameter(
            name="diagnostics_period_s", value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=2.0))])
        result = call(executor, node, SetParameters, "/aoa_localizer/set_parameters", read_only).results[0]
        assert not result.successful and "read-only" in result.reason  # fixed at start, says so
        fixes: list = []
        node.create_subscription(T.NavSatFix, "gps/fix", fixes.append, QoSProfile(depth=10))
        # the replay plays at the bag's pace once its wait for subscribers (5 s) is over: stop it while it plays
        assert spin_until(executor, lambda: fixes, 60), "the replay played nothing within 60 s"
    for p in (player, node_p):
        p.send_signal(sig)
        assert p.wait(15) == 0, open(p.log_path).read()
        log = open(p.log_path).read()
        assert "Traceback" not in log and "RCLError" not in log, log
    played = re.search(r"replayed (\d+) messages .*\(stopped by (\w+)\)", open(player.log_path).read())
    assert played and int(played[1]) > 0 and played[2] == sig.name


def test_a_node_on_sim_time_follows_a_bag_replayed_with_clock(spawn, domain):
    """ROS-package issue: with use_sim_time:=true the node's diagnostics stopped, since replay never published
    /clock. `replay --clock` publishes the bag's log time; the node's timer runs on it and it localises. The
    bearings go through remaps at both ends (replay's `--remap`, the node's `-r` as the README writes it), with no
    deprecated-syntax warning from rcl."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    spawn(["aoa_localizer.node", "--ros-args", "-p", "use_sim_time:=true", "-p", "seed:=1",
           "-r", "df/bearing:=/df1/bearing"], domain)
    with client(domain) as (node, executor):
        diags, poses = [], []
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(PoseWithCovarianceStamped, "/emitter/pose", poses.append, latched)
        replay = spawn(["aoa_localizer.replay", str(ROOT / "bags/seed"), "--clock", "--rate", "2",
                        "--remap", "/df/bearing:=/df1/bearing"], domain)
        # at twice the bag's pace (at 4x, with the suite's other workers sharing the two cores, the node once had no
        # pose at all); the allowance is the whole test's, less the processes' start
        assert spin_until(executor, lambda: len(diags) >= 5 and poses, 240), (len(diags), len(poses), replay.poll())
        assert "deprecated" not in open(replay.log_path).read()
        stamps = [d.header.stamp.sec + 1e-9 * d.header.stamp.nanosec for d in diags]
        assert stamps[-1] > stamps[0]  # moving
        assert time.time() - stamps[-1] > 600  # on the bag's clock (recorded hours before), not the wall clock


def test_an_overloaded_node_says_so_in_its_diagnostics(domain):
    """Finding 7: at 20,000 particles and 200 Hz the callbacks took 242 ms and 54 % of the records were lost,
    with diagnostics OK throughout. Work filling 90 % of a period now gives WARN and the reason; so does a period
    the node was held up in (reliability III, item 7: idle and periodic work were not counted), and the words
    hold for the period after, when what the stall lost is refused."""
    import time

    from aoa_localizer.ros.node import LocalizerNode

    rclpy.init(domain_id=domain)
    try:
        node = LocalizerNode()
        period = node.get_parameter("diagnostics_period_s").value
        mon = node.monitor
        mon.period_start = time.perf_counter()
        mon.callback_s, mon.other_s = [0.2 * period] * 3, 0.3 * period  # an idle move's work counts too
        level, message, values = node.diagnostics()
        assert level == 1 and "cannot keep up" in message and values["load_pct"] == "90"
        assert values["overload"].startswith("the node worked 90 % of the last period")
        mon.callback_s, mon.other_s = [0.01 * period] * 3, 0.0
        level, message, values = node.diagnostics()
        assert values["overload"].startswith("just before: the node worked")
        level, message, values = node.diagnostics()
        assert "overload" not in values and "cannot keep up" not in message
        mon.period_start = time.perf_counter() - 3.0 * period  # a period that lasted three: held up
        level, message, values = node.diagnostics()
        assert level == 1 and values["overload"].startswith("the node was held up")
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_messages_the_middleware_lost_make_a_warning_for_one_period(domain):
    """Reliability finding 7: a burst lost 83 % of the DF records and diagnostics stayed OK. The RMW's
    message-lost events are counted per input and WARN for the period in which they arrived."""
    from types import SimpleNamespace

    from aoa_localizer.ros.node import LocalizerNode

    rclpy.init(domain_id=domain)
    try:
        node = LocalizerNode()
        assert node.subs and all(sub.event_handlers for sub, _ in node.subs)  # the events are subscribed
        node.monitor.lost_counter("bearings_lost").message_lost(SimpleNamespace(total_count_change=7))
        level, message, values = node.diagnostics()
        assert level == 1 and "being lost" in message and values["bearings_lost"] == 7
        assert values["messages_lost"].startswith("7 input messages lost")
        level, message, values = node.diagnostics()
        assert "messages_lost" not in values and values["bearings_lost"] == 7
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_the_engines_log_lines_reach_rosout(domain):
    """The engine's Python logging (datum set, filter started, re-starts) is bridged to the node's ROS logger,
    so its lines reach /rosout like the node's own."""
    import logging

    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from aoa_localizer.ros.node import LocalizerNode

    rclpy.init(domain_id=domain)
    try:
        node = LocalizerNode()
        listener = rclpy.create_node("rosout_listener")
        seen = []
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        listener.create_subscription(Log, "/rosout", lambda m: seen.append((m.name, m.msg, m.level)), qos)
        engine = logging.getLogger("aoa_localizer.track")
        # Several severities one after another: rclpy refuses a second severity from one calling line (the node's
        # callback died of "Logger severity cannot be changed between calls" at the first datum after a warning).
        engine.info("a test line %d", 1)
        engine.warning("re-start: a test line %d", 42)
        logging.getLogger("aoa_localizer").info("a root line")  # the node's name is not repeated before it
        engine.error("a test line %d", 3)
        end = time.monotonic() + 10.0
        while time.monotonic() < end and not any("a test line 3" in msg for _, msg, _ in seen):
            rclpy.spin_once(listener, timeout_sec=0.1)
        lines = {msg: level for name, msg, level in seen if name == "aoa_localizer"}
        assert lines.get("aoa_localizer.track: a test line 1") == Log.INFO, seen
        assert lines.get("aoa_localizer.track: re-start: a test line 42") == Log.WARN
        assert lines.get("aoa_localizer.track: a test line 3") == Log.ERROR
        assert lines.get("a root line") == Log.INFO
        node.destroy_node()
        assert not logging.getLogger("aoa_localizer").handlers  # the bridge leaves with the node
        listener.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_paired_parameters_set_through_the_standard_service(spawn, domain):
    """Finding 10: datum_lat + datum_lon in one standard set_parameters request were each refused ("set
    together ... or not at all"); only the atomic service worked. A wrong value is still refused, and an unknown
    name in the engine's words (rclpy's own reason named no parameter)."""
    spawn(["aoa_localizer.node"], domain)
    with client(domain) as (node, executor):

        def req(**values):
            return SetParameters.Request(
                parameters=[
                    Parameter(name=k, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=v))
                    for k, v in values.items()
                ]
            )

        results = call(
            executor, node, SetParameters, "/aoa_localizer/set_parameters", req(datum_lat=39.1, datum_lon=117.2)
        ).results
        assert [r.successful for r in results] == [True, True], [r.reason for r in results]
        bad = call(executor, node, SetParameters, "/aoa_localizer/set_parameters", req(datum_lat=95.0)).results[0]
        assert not bad.successful and "datum_lat" in bad.reason
        typo = call(executor, node, SetParameters, "/aoa_localizer/set_parameters", req(datum_la=39.1)).results[0]
        assert not typo.successful and typo.reason == "datum_la: unknown parameter; did you mean datum_lat?"
        # Now the datum is configured: ~/reset_datum refuses to drop it, and says how to move it.
        refused = call(executor, node, Trigger, "/aoa_localizer/reset_datum", Trigger.Request())
        assert not refused.success and "datum_lat" in refused.message


def test_a_killed_recording_leaves_a_bag_that_replays_and_no_process(tmp_path, domain):
    """Reliability finding 3: SIGKILL of `launch --record` used to leave a 0-byte .mcap (nothing replayable)
    and the node and vehicle running. Now the recorder seals a chunk about every second and the children die
    with the launcher: the bag replays up to the last sealed chunk (exit 1: damaged at its end)."""
    marker = f"marker_rays:={250 + domain}"
    bag = tmp_path / "killed"
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "aoa_localizer.launch",
            "--scenario",
            "seed",
            "--speedup",
            "20",
            "--domain-id",
            str(domain),
            "--record",
            str(bag),
            "-p",
            marker.replace(":=", "="),
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        mcap = bag / "killed.mcap"
        assert wait_for(lambda: mcap.exists() and mcap.stat().st_size > 20_000, 60)  # the first sealed chunks
        time.sleep(12.0)  # most of the drive (22 s at 20x), so the sealed chunks hold enough points to start
        os.kill(p.pid, signal.SIGKILL)  # the launcher alone: its children must follow it
        p.wait(10)
        assert wait_for(lambda: no_process_with(marker), 15)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    res = subprocess.run(
        [sys.executable, "-m", "aoa_localizer.replay", bag, "--offline", "--output", tmp_path / "o.jsonl"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert res.returncode in (0, 1), res.stderr
    assert len((tmp_path / "o.jsonl").read_text().splitlines()) > 0, res.stderr


def wait_for(predicate, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.2)
    return predicate()


def test_two_ctrl_c_in_a_row_stop_the_launcher_cleanly(domain):
    """Reliability finding 3: two Ctrl-C 0.3 s apart gave a launcher traceback and left the node running."""
    marker = f"marker_rays:={350 + domain}"
    with running_launcher(domain, marker) as p:
        p.send_signal(signal.SIGINT)
        time.sleep(0.3)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=30)
        assert p.returncode == 2 and "stopped by SIGINT" in err and "Traceback" not in err, err
        assert wait_for(lambda: no_process_with(marker), 10)


def test_two_stations_and_two_emitters_each_get_their_topics_summary_and_status(spawn, domain):
    """`stations:=[car1,car2]`: each car on its own NAME/gps/fix and NAME/df/bearing, both hearing two carriers at
    the same stamps; every channel's pose under emitter/<channel>/, the summary on emitter/channels, a status per
    channel, a path per car, and nothing on the default channel's emitter/pose."""
    from aoa_localizer.simulation.fleet import PAIR, simulate_fleet

    emitters = {433.92e6: (1200.0, 800.0), 446.0e6: (300.0, 1200.0)}
    fleet = simulate_fleet(PAIR, emitters, 0)
    node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "seed:=1", "-p", "stations:=[car1,car2]",
                    "-p", "input_reliability:=reliable", "-p", "diagnostics_period_s:=0.3"], domain)
    with client(domain) as (node, executor):
        got: dict = {"status": {}, "paths": {}}
        latched = QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        for f in emitters:
            cid = f"f{int(f)}"
            node.create_subscription(T.PoseWithCovarianceStamped, f"emitter/{cid}/pose",
                                     lambda m, cid=cid: got.update({cid: m}), latched)
        node.create_subscription(T.PoseWithCovarianceStamped, "emitter/pose", lambda m: got.update(default=m),
                                 latched)
        node.create_subscription(T.String, "emitter/channels", lambda m: got.update(summary=json.loads(m.data)),
                                 latched)
        node.create_subscription(T.DiagnosticArray, "/diagnostics",
                                 lambda m: got["status"].update({st.name: st for st in m.status}), 10)
        for car in PAIR:
            node.create_subscription(T.Path, f"{car}/vehicle/path", lambda m, car=car: got["paths"].update({car: m}),
                                     10)
        reliable = QoSProfile(depth=1000)
        pubs = {(car, kind): node.create_publisher(msg, f"{car}/{topic}", reliable) for car in PAIR
                for kind, msg, topic in (("fix", T.NavSatFix, "gps/fix"), ("bearing", T.Vector3Stamped, "df/bearing"))}
        assert spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs.values()), 10)
        spin_until(executor, lambda: False, 1.0)
        for kind, car, row in fleet.events():
            if kind == "fix":
                msg = build.navsatfix(T, row[0], row[1], row[2], row[3])
            else:
                msg = build.df_record(T, row[0], row[1], row[2], row[3])
            pubs[(car, kind)].publish(msg)
            executor.spin_once(timeout_sec=0.001)
        ids = {f"f{int(f)}" for f in emitters}
        assert spin_until(executor, lambda: ids <= set(got) and ids <= set(got.get("summary", {}).get("channels", {})),
                          15), open(node_p.log_path).read()
        spin_until(executor, lambda: False, 1.5)
        frame = LocalFrame(*DATUM)
        for f, truth in emitters.items():
            cid = f"f{int(f)}"
            entry = got["summary"]["channels"][cid]
            assert entry["topics"] == f"emitter/{cid}/" and entry["frequency_hz"] == f and entry["state"] == "live"
            assert entry["transmitter_count"] == 1 and entry["transmitters"] == []  # one transmitter a frequency
            e, n = frame.to_enu(entry["lat"], entry["lon"])
            assert math.hypot(e - truth[0], n - truth[1]) < 15.0
            assert got[cid].header.frame_id == "map"
            status = got["status"][f"aoa_localizer: localizer channel {cid}"]
            assert status.level == b"\x00" and diagnostics_values(T.DiagnosticArray(status=[status]))[
                status.name]["frequency_hz"] == f"{f:.0f}"
        # Nothing came without a frequency, so emitter/pose carries a channel with the most points (the two cars
        # hear both emitters at the same stamps: a tie is usual, and the engine then keeps the first opened)
        channels = got["summary"]["channels"]
        most = max(channels[cid]["points_used"] for cid in ids)
        top = got["default"].pose.pose.position
        assert any(math.hypot(top.x - channels[cid]["east"], top.y - channels[cid]["north"]) < 0.5
                   for cid in ids if channels[cid]["points_used"] == most), (top, channels)
        assert set(got["paths"]) == set(PAIR)
        # the node's own status counts every channel's bearings (one /diagnostics message: the same moment)
        values = diagnostics_values(T.DiagnosticArray(status=list(got["status"].values())))
        per_channel = [int(values[f"aoa_localizer: localizer channel {cid}"]["bearings_used"]) for cid in ids]
        assert int(values["aoa_localizer: localizer"]["bearings_used"]) == sum(per_channel) > max(per_channel)
    assert node_p.poll() is None


def test_a_full_disk_stops_the_recording_not_the_run(tmp_path, domain):
    """Reliability III, item 10: a full disk ended `launch --record` with a chained OSError traceback and exit 1.
    The disk fills here through the file size limit (writes past it fail with EFBIG, as with ENOSPC)."""
    import resource

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, 150_000))

    bag = tmp_path / "full"
    res = subprocess.run([sys.executable, "-m", "aoa_localizer.launch", "--scenario", "seed", "--speedup", "80",
                          "--seed", "2", "--domain-id", str(domain), "--record", str(bag)], cwd=ROOT,
                         capture_output=True, text=True, timeout=180, preexec_fn=small_files)
    assert res.returncode == 0, res.stdout + res.stderr
    # the write that meets the limit may be a message's or a chunk's seal: either stops the recording
    assert "recording stopped early (File too large while" in res.stdout, res.stdout
    assert "Traceback" not in res.stdout + res.stderr
    assert "error against the simulated truth" in res.stdout
    replay = subprocess.run([sys.executable, "-m", "aoa_localizer.replay", bag, "--offline", "--output",
                             tmp_path / "o.jsonl"], cwd=ROOT, capture_output=True, text=True)
    assert replay.returncode in (0, 1), replay.stderr  # what was written before is read


def test_hostile_records_and_parameters_cost_only_themselves_through_the_graph(spawn, domain):
    """Reliability III, items 1, 2 and 5 through the graph: a record stamped 1e9 s ahead on another frequency
    silently stopped all localisation; vector.z = 1e300 crashed the node (an invalid topic name, rc 1);
    afsa.try_number 1e9 passed validation and then crashed the node."""
    node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "seed:=1", "-p", "input_reliability:=reliable",
                    "-p", "diagnostics_period_s:=0.5"], domain)
    emitter = (600.0, 400.0)
    with client(domain) as (node, executor):
        got, diag = {}, {}
        latched = QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(T.PoseWithCovarianceStamped, "emitter/pose", lambda m: got.update(pose=m), latched)
        node.create_subscription(T.DiagnosticArray, "/diagnostics",
                                 lambda m: diag.update(diagnostics_values(m).get("aoa_localizer: localizer", {})), 10)
        hostile = node.create_publisher(T.Vector3Stamped, "df/bearing", QoSProfile(depth=100))
        assert spin_until(executor, lambda: hostile.get_subscription_count(), 10)
        spin_until(executor, lambda: False, 1.0)  # the node's end of the match settled too (as _drive_publishers)
        _publish_drive(node, executor, emitter, seconds=20.0)
        # the node drains the drive's burst first: on a loaded machine its input queue overflowed (a hundred of the
        # drive's records missing by stamp) and took the hostile two with it
        spin_until(executor, lambda: False, 1.0)
        hostile.publish(build.df_record(T, 1000.0 + 20.0 + 1e9, 10.0, 90.0, 123e6))  # far ahead, another channel
        hostile.publish(build.df_record(T, 1020.05, 10.0, 90.0, 1e300))  # no receiver's frequency
        _publish_drive(node, executor, emitter, seconds=40.0, start_east=400.0, t0=1021.0)
        assert spin_until(executor, lambda: "pose" in got and diag.get("rejected.bad_frequency") == "1"
                          and diag.get("rejected.bearing_stamp_jump") == "1", 15), json.dumps(diag)
        # every record but the two hostile ones and the last open points used, once the node has drained its queue
        # and the records parked for their fixes (a busy machine's node takes seconds more)
        assert spin_until(executor, lambda: int(diag["bearings_used"]) >= int(diag["bearings_received"]) - 10
                          and diag.get("df_waiting_for_fix") == "0", 30), json.dumps(diag)
        assert not any(k in diag for k in ("rejected.gps_gap", "events.df_clock_jump")), json.dumps(diag)
        _, east, north, _ = estimate_from_pose(got["pose"])
        assert math.hypot(east - emitter[0], north - emitter[1]) < 15.0
        bad = SetParameters.Request(parameters=[Parameter(
            name="afsa.try_number", value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=10**9))])
        result = call(executor, node, SetParameters, "/aoa_localizer/set_parameters", bad).results[0]
        assert not result.successful and "afsa.try_number" in result.reason
    assert node_p.poll() is None
    assert "Traceback" not in open(node_p.log_path).read()


def test_two_nodes_split_twenty_emitters_by_band_and_each_is_localised_once(spawn, domain):
    """`frequency_band_hz`: two nodes in their own namespaces read one receiver's shared gps/fix and df/bearing,
    each over half the spectrum; every one of 20 emitters is on exactly one node's emitter/channels, near its
    truth, and each node counts the other's records as `other_band` (scripts/band_split.py runs 50, offline)."""
    from dataclasses import replace

    from aoa_localizer.simulation.fleet import simulate_fleet
    from aoa_localizer.simulation.scenarios import SCENARIOS

    rng = np.random.default_rng(7)
    emitters = {400e6 + 25e3 * k: (float(rng.uniform(300, 1800)), float(rng.uniform(300, 1300))) for k in range(20)}
    split = 400e6 + 25e3 * 10
    bands = {"low": [400e6, split], "high": [split, 402e6]}
    fleet = simulate_fleet({"": replace(SCENARIOS["seed"], points=20)}, emitters, 0)
    for name, band in bands.items():
        spawn(["aoa_localizer.node", "--ros-args", "-r", f"__ns:=/{name}", "-r", "gps/fix:=/gps/fix",
               "-r", "df/bearing:=/df/bearing", "-p", f"frequency_band_hz:=[{band[0]:.1f},{band[1]:.1f}]",
               "-p", "seed:=1", "-p", "input_reliability:=reliable", "-p", "input_queue_depth:=20000",
               "-p", "diagnostics_period_s:=0.5"], domain)
    with client(domain) as (node, executor):
        got: dict = {}
        latched = QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)
        for name in bands:
            node.create_subscription(T.String, f"/{name}/emitter/channels",
                                     lambda m, name=name: got.update({name: json.loads(m.data)["channels"]}), latched)
        node.create_subscription(T.DiagnosticArray, "/diagnostics", lambda m: got.update(  # "<ns>/aoa_localizer: ..."
            {f"diag {s.name.split('/')[0]}": s for s in m.status if s.name.endswith(": localizer")}), 10)
        reliable = QoSProfile(depth=20000)
        fix_pub = node.create_publisher(T.NavSatFix, "/gps/fix", reliable)
        df_pub = node.create_publisher(T.Vector3Stamped, "/df/bearing", reliable)
        assert spin_until(executor, lambda: fix_pub.get_subscription_count() == 2
                          and df_pub.get_subscription_count() == 2, 15)
        spin_until(executor, lambda: False, 1.0)
        start, first = time.monotonic(), None
        for kind, _, row in fleet.events():  # at 50x the receiver's pace: a burst would reach the node unpaired
            first = row[0] if first is None else first
            while time.monotonic() - start < (row[0] - first) / 50.0:
                executor.spin_once(timeout_sec=0.001)
            if kind == "fix":
                fix_pub.publish(build.navsatfix(T, row[0], row[1], row[2], row[3]))
            else:
                df_pub.publish(build.df_record(T, row[0], row[1], row[2], row[3]))
        everyone = {f"f{int(f)}" for f in emitters}
        assert spin_until(executor, lambda: set(got.get("low", {})) | set(got.get("high", {})) == everyone, 60), (
            sorted(everyone - set(got.get("low", {})) - set(got.get("high", {}))))
        assert not set(got["low"]) & set(got["high"])  # each emitter on one node only
        frame = LocalFrame(*DATUM)
        outside = []
        for name, band in bands.items():
            for cid, entry in got[name].items():
                assert band[0] <= entry["frequency_hz"] < band[1]
                e, n = frame.to_enu(entry["lat"], entry["lon"])
                truth = emitters[entry["frequency_hz"]]
                miss, bound = math.hypot(e - truth[0], n - truth[1]), max(30.0, entry["ellipse95_major_m"])
                assert miss < 3.0 * bound, (cid, entry)  # no emitter lost
                if miss >= bound:
                    outside.append((cid, round(miss, 1), bound))
        # Honest ellipses leave an emitter outside its 95 % semi-major now and then (1-5 % each: 20 emitters make
        # one a run at times; a busy machine's node, behind the 50x stream, closes points later): a few, not many
        assert len(outside) <= 3, outside
        assert spin_until(executor, lambda: all(f"diag {name}" in got for name in bands), 5)
        for name in bands:
            values = diagnostics_values(T.DiagnosticArray(status=[got[f"diag {name}"]]))[got[f"diag {name}"].name]
            assert int(values["other_band"]) > 0 and "rejected.bad_frequency" not in values


def test_a_burst_of_parameter_sets_is_one_restart_with_the_last_values(spawn, domain):
    """Issue 51, item 4: each set used to restart the track at once (about 150 ms each), and a 2 s burst was still
    being applied 138 s later. Now each set is only checked and accepted; the track restarts once the sets pause,
    with the last value of each, and /diagnostics counts both."""
    spawn(["aoa_localizer.node", "--ros-args", "-p", "diagnostics_period_s:=0.5"], domain)
    with client(domain) as (node, executor):
        diag = {}
        node.create_subscription(T.DiagnosticArray, "/diagnostics", lambda m: diag.update(
            diagnostics_values(m).get("aoa_localizer: localizer", {})), 10)
        started, sent = time.monotonic(), []
        for k in range(40):
            req = SetParameters.Request(parameters=[Parameter(name="num_particles", value=ParameterValue(
                type=ParameterType.PARAMETER_INTEGER, integer_value=150 + k))])
            assert call(executor, node, SetParameters, "/aoa_localizer/set_parameters", req,
                        sent=sent).results[0].successful
        burst_s = time.monotonic() - started
        # each set sent is counted (a busy machine's slow answer makes call() send one again)
        assert spin_until(executor, lambda: diag.get("parameter_changes") == str(sum(sent)), 15), json.dumps(diag)
        assert spin_until(executor, lambda: int(diag.get("restarts", 0)) >= 1, 5), json.dumps(diag)
        spin_until(executor, lambda: False, 1.5)
        assert 1 <= int(diag["restarts"]) <= 2 + burst_s  # one a quiet pause (or a second of burst), not one a set
        got = call(executor, node, GetParameters, "/aoa_localizer/get_parameters",
                   GetParameters.Request(names=["num_particles"]))
        assert got.values[0].integer_value == 189  # the last value won


def test_a_whole_number_for_a_decimal_parameter_is_that_decimal_at_start_and_at_run_time(spawn, domain):
    """Issue 53, item 5: `-p goal_radius_m:=200` was refused ("expecting type 'DOUBLE'"), at start and at run time."""
    node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "goal_radius_m:=200"], domain)
    with client(domain) as (node, executor):
        req = SetParameters.Request(parameters=[Parameter(name="gps_max_gap_s", value=ParameterValue(
            type=ParameterType.PARAMETER_INTEGER, integer_value=3))])
        assert call(executor, node, SetParameters, "/aoa_localizer/set_parameters", req).results[0].successful
        got = call(executor, node, GetParameters, "/aoa_localizer/get_parameters",
                   GetParameters.Request(names=["goal_radius_m", "gps_max_gap_s"]))
        assert [(v.type, v.double_value) for v in got.values] == [(ParameterType.PARAMETER_DOUBLE, 200.0),
                                                                  (ParameterType.PARAMETER_DOUBLE, 3.0)]
    assert node_p.poll() is None


def test_a_domain_with_another_graph_is_refused_and_its_publishers_named(domain):
    """Issue 53, item 1: a launcher in a domain where another graph publishes (here a client on gps/fix) is refused
    with exit 2, naming it, before it starts anything. Discovery on a loaded machine may show the other graph only
    after the launcher's look (1.5 s): then the node names it and the run is judged not converged, naming it; never
    a silent "converged" on mixed data."""
    with client(domain, name="other_graph") as (node, executor):
        pub = node.create_publisher(T.NavSatFix, "gps/fix", 10)
        spin_until(executor, lambda: False, 0.5)
        res = launch(["--scenario", "seed", "--speedup", 40, "--domain-id", domain], timeout=120)
        assert pub is not None
    if res.returncode == 2:
        assert f"ROS_DOMAIN_ID {domain} already has publishers" in res.stderr
        assert "other_graph on /gps/fix" in res.stderr
        assert "logs in" not in res.stdout  # nothing was started
    else:
        assert res.returncode == 1 and "another source published on the node's inputs" in res.stdout + res.stderr
        assert "other_graph" in res.stdout + res.stderr


def test_another_graph_joining_during_the_run_makes_it_not_converged(domain):
    """A graph that joins the launcher's domain mid-run (a second publisher on gps/fix): the node names it, the
    launcher says so and the run is judged not converged, naming it (issue 53, item 1: `bearings received 29536`
    where the scenario sends 300, exit 1 for a reason nobody was told)."""
    p = subprocess.Popen([sys.executable, "-m", "aoa_localizer.launch", "--scenario", "seed", "--speedup", "40",
                          "--domain-id", str(domain)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, start_new_session=True)
    try:
        assert "logs in" in p.stdout.readline()  # the domain was free: the run has started
        with client(domain, name="late_graph") as (node, executor):
            node.create_publisher(T.NavSatFix, "gps/fix", 10)
            while p.poll() is None:
                spin_until(executor, lambda: False, 0.2)
            out, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 1, out + err
    assert "another source publishes on the node's inputs" in err and "late_graph" in err
    assert "result: another source published on the node's inputs during the run" in out


def test_the_launcher_names_another_source_once_discovery_names_it(capsys):
    """The node first sees a late graph's publisher before its name (rmw's unnamed node): the launcher says so, and
    says it again once the name arrives, so the run's verdict names it (a busy machine's discovery lagged past the
    first /diagnostics: CI49); a warning that does not change is said once, and at most CROWDED_LINES in all."""
    from types import SimpleNamespace as NS

    from aoa_localizer.ros.launch import CROWDED_LINES, Monitor

    def diagnostics(publishers: str):
        kv = [NS(key="input_publishers", value=publishers)]
        return NS(status=[NS(name="aoa_localizer: localizer", values=kv, level=1, message="WARN")])

    monitor = NS(diag=None, diagnostics_seen=0, worst_diag=(0, ""), crowded="", crowded_said=0)
    unnamed = "/gps/fix has 2 publishers (/sim_vehicle, a node not named yet (01b2c3d4))"
    named = "/gps/fix has 2 publishers (/late_graph, /sim_vehicle)"
    for text in (unnamed, unnamed, named, named):
        Monitor._on_diagnostics(monitor, diagnostics(text))
    err = capsys.readouterr().err
    assert err.count("another source publishes on the node's inputs") == 2 and monitor.crowded == named
    for k in range(10):
        Monitor._on_diagnostics(monitor, diagnostics(f"/gps/fix has 2 publishers (/other_{k}, /sim_vehicle)"))
    assert capsys.readouterr().err.count("another source") == CROWDED_LINES - 2


def test_the_launcher_judges_from_the_nodes_first_input_and_says_what_the_node_never_took():
    """A busy machine's replay can outrun a node still loading and its input queue (CI77: 39 of 2422 bearings
    taken, "diagnostics: OK throughout"): the launcher counts the run's diagnostics from the node's first
    input (before it, "no DF reading since the start" is the source still starting) and compares what the node
    took with what the bag holds (bags/urban/metadata.yaml: 244 fixes, 2422 bearings)."""
    from types import SimpleNamespace as NS

    from aoa_localizer.ros.launch import Monitor, inputs_lost

    def diagnostics(level: int, fixes: int):
        kv = [NS(key="fixes_received", value=str(fixes)), NS(key="bearings_received", value="0")]
        return NS(status=[NS(name="aoa_localizer: localizer", values=kv, level=level, message=f"level {level}")])

    monitor = NS(diag=None, diagnostics_seen=0, worst_diag=(0, ""), crowded="", crowded_said=0)
    Monitor._on_diagnostics(monitor, diagnostics(1, 0))
    assert monitor.worst_diag == (0, "")
    Monitor._on_diagnostics(monitor, diagnostics(1, 3))
    assert monitor.worst_diag[0] == 1
    args = NS(bag=ROOT / "bags/urban", scenario="urban")
    said = inputs_lost(args, {}, {"fixes_received": "244", "bearings_received": "39"})
    assert said is not None and "39 of 2422 bearings" in said and "fixes" not in said and "--rate" in said
    assert inputs_lost(args, {}, {"fixes_received": "244", "bearings_received": "2422"}) is None


def test_two_sources_on_one_input_topic_are_named_in_the_diagnostics(spawn, domain):
    """Issue 53, item 1: the node says when one of its inputs has more than one publisher (another graph in its
    domain, or two receivers on one station's topic): WARN, `input_publishers` naming both."""
    node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "diagnostics_period_s:=0.3"], domain)
    with client(domain, name="receiver_a") as (a, executor), client(domain, name="receiver_b") as (b, other):
        a.create_publisher(T.Vector3Stamped, "df/bearing", 10)
        b.create_publisher(T.Vector3Stamped, "df/bearing", 10)
        diag: dict = {}
        a.create_subscription(T.DiagnosticArray, "/diagnostics", lambda m: diag.update(
            diagnostics_values(m).get("aoa_localizer: localizer", {})), 10)
        # named once discovery has both names (an endpoint may come before its node's name)
        assert spin_until(executor, lambda: all(n in diag.get("input_publishers", "") for n in (
            "/receiver_a", "/receiver_b")), 20), json.dumps(diag)
        other.spin_once(timeout_sec=0.01)
    assert "/df/bearing has 2 publishers" in diag["input_publishers"] and diag["level"] == "1"
    assert "/receiver_a" in diag["input_publishers"] and "/receiver_b" in diag["input_publishers"]
    assert node_p.poll() is None


def test_two_nodes_with_one_name_are_named_in_the_diagnostics(spawn, domain):
    """Issue 51, item 14: two nodes started with one name share one /diagnostics name and one ~/reset, unwarned.
    Each now says so: WARN, `node_name`, and a log line."""
    args = ["aoa_localizer.node", "--ros-args", "-p", "diagnostics_period_s:=0.3"]
    first, second = spawn(args, domain), spawn(args, domain)
    with client(domain, name="watcher") as (node, executor):
        diag: dict = {}
        node.create_subscription(T.DiagnosticArray, "/diagnostics", lambda m: diag.update(
            diagnostics_values(m).get("aoa_localizer: localizer", {})), 10)
        assert spin_until(executor, lambda: "node_name" in diag, 20), json.dumps(diag)
    assert "2 nodes are named /aoa_localizer" in diag["node_name"] and diag["level"] == "1"
    assert "__node:=" in diag["node_name"]
    assert first.poll() is None and second.poll() is None


def test_the_node_sends_each_estimate_to_tak_as_cursor_on_target(spawn, domain):
    """Issue 53, part 3, and issue 67, item 5: `cot_url:=udp://127.0.0.1:PORT` (a TAK receiver's UDP input on this
    machine, read by pytak, a TAK client from PyPI): CoT events arrive as the estimate changes (at most one a
    cot_period_s: the drive's points come in two seconds here) with a point and CE90 that the node published on
    emitter/fix, and /diagnostics counts them; a cot_url the node cannot use refuses the start."""
    import xml.etree.ElementTree as ET

    from tak_listener import PytakListener

    emitter = (600.0, 400.0)
    fixes: list = []
    with PytakListener() as tak, client(domain) as (node, executor):
        node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "seed:=1", "-p", "diagnostics_period_s:=0.3",
                        "-p", f"cot_url:={tak.url}"], domain)
        diag: dict = {}
        node.create_subscription(T.DiagnosticArray, "/diagnostics", lambda m: diag.update(
            diagnostics_values(m).get("aoa_localizer: localizer", {})), 10)
        node.create_subscription(T.NavSatFix, "emitter/fix", fixes.append, QoSProfile(depth=1000))
        _publish_drive(node, executor, emitter)
        assert spin_until(executor, lambda: len(tak.events) >= 1, 20), open(node_p.log_path).read()
        spin_until(executor, lambda: False, 1.5)  # the drive's last points, and a diagnostics period
        assert spin_until(executor, lambda: int(diag.get("cot_sent", 0)) == len(tak.events), 5), json.dumps(diag)
        last = ET.fromstring(tak.events[-1])
        point = last.find("point")
        lat, lon, ce = (float(point.get(k)) for k in ("lat", "lon", "ce"))

        def held() -> list[tuple[float, float]]:
            """The share of each fix at the event's point (to CoT's 1e-7 deg) that its CE90 circle holds, counted
            over draws from the fix's east-north covariance, not by the node's formula, at the CE's 0.1 m rounding's
            two ends."""
            out = []
            for f in fixes:
                if abs(f.latitude - lat) < 2e-7 and abs(f.longitude - lon) < 2e-7:
                    c = np.array(f.position_covariance, float).reshape(3, 3)[:2, :2]
                    r = np.hypot(*np.random.default_rng(0).multivariate_normal([0.0, 0.0], c, 200_000).T)
                    out.append((float(np.mean(r <= ce - 0.05)), float(np.mean(r <= ce + 0.05))))
            return out

        # the event is one the node published: several fixes may share its point, and the event's own fix may reach
        # this client after the event reached pytak
        assert spin_until(executor, lambda: any(lo - 0.005 <= 0.9 <= hi + 0.005 for lo, hi in held()), 5), (
            lat, lon, held(), [(f.latitude, f.longitude) for f in fixes[-3:]])
    assert last.get("uid") == "aoa_localizer.default" and last.get("type") == "a-u-G"
    east, north = LocalFrame(*DATUM).to_enu(lat, lon)
    assert math.hypot(east - emitter[0], north - emitter[1]) < 30.0
    assert diag["cot_failed"] == "0"
    refused = subprocess.run([sys.executable, "-m", "aoa_localizer.node", "--ros-args", "-p", "cot_url:=http://x:1"],
                             env=ros_env(domain), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "the scheme must be udp:// or tcp://" in refused.stderr


def test_a_tak_server_that_is_down_makes_the_diagnostics_warn_and_the_log_say_it(spawn, domain):
    """Issue 67, item 5: with nothing listening, /diagnostics stayed OK with cot_failed=14 and no log line."""
    import socket

    closed = socket.socket()
    closed.bind(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()  # nobody listens on it
    node_p = spawn(["aoa_localizer.node", "--ros-args", "-p", "seed:=1", "-p", "diagnostics_period_s:=0.3", "-p",
                    f"cot_url:=tcp://127.0.0.1:{port}"], domain)
    with client(domain) as (node, executor):
        diag: dict = {}
        diag_count = [0]

        def on_diagnostics(m) -> None:
            mine = diagnostics_values(m).get("aoa_localizer: localizer")
            if mine:
                diag.update(mine)
                diag_count[0] += 1

        node.create_subscription(T.DiagnosticArray, "/diagnostics", on_diagnostics, 10)
        _publish_drive(node, executor, (600.0, 400.0))
        assert spin_until(executor, lambda: "TAK:" in diag.get("message", ""), 20), json.dumps(diag)
        # still said periods later, with no estimate due (it once lasted the one period the count grew in)
        periods = diag_count[0]
        assert spin_until(executor, lambda: diag_count[0] >= periods + 3, 10), json.dumps(diag)
        assert "TAK:" in diag["message"] and diag["level"] in ("1", "2") and int(diag["cot_failed"]) >= 1, diag
    assert "TAK: " in open(node_p.log_path).read() and "not sent" in open(node_p.log_path).read()


def test_a_vehicle_publishing_scans_is_localised_on_every_channel(domain):
    """Issue 69: `bearing_encoding:=scan` makes the vehicle publish each stamp's readings of its two transmitters as
    one PointCloud2 on df/scan (and nothing on df/bearing); the node, on its defaults, localises both."""
    res = launch(["--scenario", "seed", "--speedup", 80, "--seed", 1, "--domain-id", domain, "--vehicle-param",
                  "emitters=[433.92e6,1200,800,446e6,400,1100]", "--vehicle-param", "bearing_encoding=scan"])
    assert res.returncode == 0, res.stdout + res.stderr
    for channel in ("f433920000", "f446000000"):
        line = next(x for x in res.stdout.splitlines() if x.startswith(f"channel {channel}:"))
        assert float(re.search(r"error against its truth ([0-9.]+) m", line).group(1)) < 10.0, line


def test_the_launcher_reports_every_transmitter_against_its_own_truth(domain):
    """Issue 53, items 2 and 5: `--vehicle-param emitters=[433.92e6,...]` (numbers YAML 1.1 reads as text, as
    `simulate --emitters` takes them) plays two transmitters; the vehicle publishes each one's truth on
    sim/<channel>/truth and the launcher reports every channel against its own."""
    res = launch(["--scenario", "seed", "--speedup", 80, "--seed", 1, "--domain-id", domain, "--vehicle-param",
                  "emitters=[433.92e6,1200,800,446e6,400,1100]"])
    assert res.returncode == 0, res.stdout + res.stderr
    for channel in ("f433920000", "f446000000"):
        line = next(x for x in res.stdout.splitlines() if x.startswith(f"channel {channel}:"))
        error = float(re.search(r"error against its truth ([0-9.]+) m", line).group(1))
        assert error < 10.0, line
