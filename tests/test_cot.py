"""Cursor-on-Target for TAK (issue 53, part 3): the event an estimate makes, parsed as a TAK receiver would
(takproto, the TAK protocol's maintained library), and sent over UDP and TCP to listeners on this machine."""
import socket
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import takproto
from tak_listener import PytakListener

from aoa_localizer.common import cot
from aoa_localizer.common.cot import QUEUE_MAX, CotSender, estimate_event, parse_cot_url, write_cot_files
from aoa_localizer.engine.types import Estimate


@pytest.fixture
def estimate():
    # 95 % ellipse: semi-axes sqrt(5.99 * 9) = 7.34 m north-south and sqrt(5.99 * 1) = 2.45 m east-west
    return Estimate(12.0, 100.0, 200.0, 39.1072166, 117.2138794, np.array([[1.0, 0.0], [0.0, 9.0]]), 250, 50, 80.0,
                    "afsa", channel="f433920000", frequency_hz=433.92e6, state="tracking")


def test_an_estimate_is_a_cot_event_with_its_point_ellipse_and_state(estimate):
    event = ET.fromstring(estimate_event(estimate, 60.0))
    assert event.get("uid") == "aoa_localizer.f433920000" and event.get("type") == "a-u-G"
    point = event.find("point")
    assert float(point.get("lat")) == 39.1072166 and float(point.get("lon")) == 117.2138794
    # CoT's ce is CE90, the circle holding 90 % (ATAK's CotPoint): for sigmas 3 m and 1 m, 5.05 m (a Monte Carlo
    # check below); the height is not estimated (le, hae: CoT's 9999999, unknown)
    assert float(point.get("ce")) == pytest.approx(5.05, abs=0.05)
    rng = np.random.default_rng(0)
    draws = rng.multivariate_normal([0.0, 0.0], np.diag([1.0, 9.0]), 200_000)
    assert np.mean(np.hypot(*draws.T) <= float(point.get("ce"))) == pytest.approx(0.9, abs=0.005)
    assert float(point.get("le")) == float(point.get("hae")) == 9999999.0
    ellipse = event.find("detail/shape/ellipse")
    assert float(ellipse.get("major")) == pytest.approx(7.3, abs=0.1) and float(ellipse.get("minor")) == pytest.approx(
        2.4, abs=0.1) and float(ellipse.get("angle")) in (0.0, 180.0)  # the major axis north-south
    remarks = event.find("detail/remarks").text
    assert "433.920 MHz" in remarks and "tracking" in remarks and "250 bearings" in remarks
    assert event.find("detail/contact").get("callsign") == "DF f433920000"
    assert event.get("stale") > event.get("time")
    # what a TAK receiver makes of it: the TAK protocol's own library reads the same event
    proto = takproto.parse_proto(takproto.xml2proto(ET.tostring(event).decode()))
    assert proto.cotEvent.uid == "aoa_localizer.f433920000" and proto.cotEvent.lat == pytest.approx(39.1072166)


def test_a_moving_transmitter_carries_its_course_and_speed_as_a_cot_track(estimate):
    from dataclasses import replace

    assert ET.fromstring(estimate_event(estimate, 60.0)).find("detail/track") is None  # standing: no track
    moving = replace(estimate, motion="moving", motion_probability=0.97, velocity=np.array([-3.0, 4.0]),
                     velocity_cov=np.eye(2))
    track = ET.fromstring(estimate_event(moving, 60.0)).find("detail/track")
    assert float(track.get("speed")) == pytest.approx(5.0)
    assert float(track.get("course")) == pytest.approx(323.1, abs=0.05)  # west of north: atan2(-3, 4)
    proto = takproto.parse_proto(takproto.xml2proto(estimate_event(moving, 60.0).decode()))
    assert proto.cotEvent.detail.track.speed == pytest.approx(5.0)
    assert proto.cotEvent.detail.track.course == pytest.approx(323.1, abs=0.05)  # as written, to 0.1 deg


def test_udp_and_tcp_listeners_receive_the_event_and_a_dead_server_is_counted_not_raised(estimate, tmp_path):
    payload = estimate_event(estimate, 60.0)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5)
    udp = CotSender(f"udp://127.0.0.1:{rx.getsockname()[1]}")
    udp.send(payload)
    assert rx.recv(65536) == payload and udp.flush() and udp.sent == 1 and not udp.failing
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    tcp = CotSender(f"tcp://127.0.0.1:{port}")
    tcp.send(payload)
    conn, _ = server.accept()
    conn.settimeout(5)
    assert conn.recv(65536).rstrip(b"\n") == payload
    conn.close()
    server.close()
    dead = CotSender(f"tcp://127.0.0.1:{port}")  # nobody listens any more
    dead.send(payload)
    assert dead.flush() and dead.failed == 1 and "ConnectionRefused" in dead.last_error
    dead.send(payload)
    assert dead.flush() and dead.failed == 2 and dead.failing  # within RETRY_S: not tried again, counted
    for sender in (udp, tcp, dead):
        sender.close()
    assert write_cot_files(tmp_path, [estimate]) == "1 .cot file for TAK"
    assert (tmp_path / "emitter_f433920000.cot").read_bytes().startswith(b"<?xml")


def test_a_tak_server_down_is_failing_until_an_event_is_sent_again(estimate, monkeypatch):
    """A down server was one /diagnostics period's warning (the count grew once, then no estimate was due): the
    sender says it is failing from the first failure until a send succeeds."""
    monkeypatch.setattr(cot, "RETRY_S", 0.0)
    payload = estimate_event(estimate, 60.0)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    server.close()
    sender = CotSender(f"tcp://127.0.0.1:{port}")
    sender.send(payload)
    assert sender.flush() and sender.failing and sender.failed == 1
    server = socket.create_server(("127.0.0.1", port))  # the server is back
    sender.send(payload)
    conn, _ = server.accept()
    assert sender.flush() and not sender.failing and sender.sent == 1 and sender.failed == 1
    conn.close()
    server.close()
    sender.close()


@pytest.mark.parametrize("bad", ["http://host:80", "udp://", "tcp+ro://host:8087", "udp://127.0.0.1:99999",
                                 "udp://127.0.0.1:-1", "udp://127.0.0.1:70000", "udp://127.0.0.1:0", "udp://host",
                                 "udp://user:pw@host:6969", "udp://[::1", "tcp://host:8087/path", "udp://h:x"])
def test_a_cot_url_that_cannot_work_is_refused_at_start(bad):
    """Issue 64, item 9: ports outside 0-65535 were taken at start and the node died at its first estimate
    (OverflowError from sendto); no port, credentials and brackets were taken and could never work."""
    with pytest.raises(ValueError, match="cot_url"):
        parse_cot_url(bad)
    with pytest.raises(ValueError, match="cot_url"):
        CotSender(bad)


def test_ipv6_works_and_a_host_that_does_not_resolve_is_counted_not_raised(estimate):
    payload = estimate_event(estimate, 60.0)
    assert parse_cot_url("udp://[::1]:6969") == (False, "::1", 6969)
    rx = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    rx.bind(("::1", 0))
    rx.settimeout(5)
    six = CotSender(f"udp://[::1]:{rx.getsockname()[1]}")
    six.send(payload)
    assert rx.recv(65536) == payload
    nowhere = CotSender("udp://no-such-host.invalid:6969")
    nowhere.send(payload)
    assert nowhere.flush() and nowhere.failed == 1 and nowhere.last_error
    for sender in (six, nowhere):
        sender.close()


def test_a_tak_server_that_never_reads_costs_the_caller_nothing(estimate):
    """Issue 64, item 6: `send` ran in the node's input callback with a 2 s timeout; a server that accepts and
    never reads held the pose latency at 2 s with 40 channels. Now send only queues: 500 events in well under a
    second while the sender's thread is stuck, the oldest beyond QUEUE_MAX dropped and counted."""
    import time

    payload = estimate_event(estimate, 60.0) * 200  # 100 kB an event: the socket's buffers fill at once
    server = socket.create_server(("127.0.0.1", 0))
    server.listen()
    stuck = CotSender(f"tcp://127.0.0.1:{server.getsockname()[1]}")
    start = time.monotonic()
    for _ in range(500):
        stuck.send(payload)
    assert time.monotonic() - start < 10.0  # 500 x the 2 s timeout, were the sends made here
    assert stuck.dropped >= 500 - QUEUE_MAX - 2
    stuck.close()
    server.close()


def test_pytaks_own_reader_receives_the_event_with_the_estimates_point_and_error(estimate):
    """Issue 67, item 5: a TAK client from PyPI (pytak's UDP reader and receive worker) takes the event off the
    wire; its point, CE90 and ellipse are the estimate's."""
    with PytakListener() as tak:
        sender = CotSender(tak.url)
        deadline = time.monotonic() + 10
        while not tak.events and time.monotonic() < deadline:  # UDP: sent again until pytak has read one
            sender.send(estimate_event(estimate, 60.0))
            time.sleep(0.05)
        sender.close()
    assert tak.events, "pytak read nothing"
    event = ET.fromstring(tak.events[0])
    point = event.find("point")
    assert float(point.get("lat")) == estimate.lat and float(point.get("lon")) == estimate.lon
    assert float(point.get("ce")) == pytest.approx(5.05, abs=0.05)  # CE90 of sigmas 3 m and 1 m (above)
    assert float(event.find("detail/shape/ellipse").get("major")) == pytest.approx(7.3, abs=0.1)
