"""Cursor-on-Target for TAK (issue 53, part 3): the event an estimate makes, parsed as a TAK receiver would
(takproto, the TAK protocol's maintained library), and sent over UDP and TCP to listeners on this machine."""
import math
import socket
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import takproto

from aoa_localizer.common.cot import CotSender, estimate_event, write_cot_files
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
    assert float(point.get("ce")) == pytest.approx(math.sqrt(5.991 * 9.0), abs=0.1)
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


def test_udp_and_tcp_listeners_receive_the_event_and_a_dead_server_is_counted_not_raised(estimate, tmp_path):
    payload = estimate_event(estimate, 60.0)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5)
    udp = CotSender(f"udp://127.0.0.1:{rx.getsockname()[1]}")
    assert udp.send(payload) and rx.recv(65536) == payload and udp.sent == 1
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    tcp = CotSender(f"tcp://127.0.0.1:{port}")
    assert tcp.send(payload)
    conn, _ = server.accept()
    conn.settimeout(5)
    assert conn.recv(65536).rstrip(b"\n") == payload
    conn.close()
    server.close()
    dead = CotSender(f"tcp://127.0.0.1:{port}")  # nobody listens any more
    assert not dead.send(payload) and dead.failed == 1 and "ConnectionRefused" in dead.last_error
    assert not dead.send(payload) and dead.failed == 2  # within RETRY_S: not tried again, counted
    for bad in ("http://host:80", "udp://", "tcp+ro://host:8087"):
        with pytest.raises(ValueError):
            CotSender(bad)
    assert write_cot_files(tmp_path, [estimate]) == "1 .cot file for TAK"
    assert (tmp_path / "emitter_f433920000.cot").read_bytes().startswith(b"<?xml")
