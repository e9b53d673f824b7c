"""Cursor-on-Target for TAK (ATAK, WinTAK, iTAK): an emitter estimate as a CoT event, encoded by pytak (an
optional extra, `pip install 'aoa_localizer[tak]'`), and a sender for pytak's URL convention (`udp://host:port`,
unicast, broadcast or multicast such as udp://239.2.3.1:6969; `tcp://host:port`). The event is the emitter's point
with the 95 % ellipse as its circular error and as a CoT ellipse shape, the state and the ellipse in the remarks,
and a stale time after which TAK greys it out (docs/interface.md, "TAK")."""
from __future__ import annotations

import math
import socket
import threading
import time
import warnings
import xml.etree.ElementTree as ET
from collections import deque
from pathlib import Path
from urllib.parse import urlsplit

from aoa_localizer.common.output import file_names
from aoa_localizer.common.xml_text import xml_text
from aoa_localizer.engine.crlb import ELLIPSE_95, circular_error, ellipse_axes

RETRY_S = 10.0  # after a failed send, the next tries this much later (a TCP server down costs no 2 s timeouts)
COT_TYPE = "a-u-G"  # an unknown ground object: what a transmitter found by DF is until someone says more
UID_PREFIX = "aoa_localizer"


class CotUnavailable(RuntimeError):
    """pytak is not installed: the message says how to install it."""


def _pytak():
    try:
        with warnings.catch_warnings():  # pytak warns about extras (cryptography, aiohttp) we do not use
            warnings.simplefilter("ignore")
            import pytak
    except ImportError as exc:
        raise CotUnavailable("CoT needs pytak: pip install 'aoa_localizer[tak]' (or pytak)") from exc
    return pytak


def estimate_event(est, stale_s: float, name: str = "") -> bytes:
    """One estimate as a CoT event (XML bytes): uid `aoa_localizer.<channel or name>`, its point to 1e-7 deg, `ce`
    its CE90 (m; `le` and `hae` unknown), a shape with the 95 % ellipse (semi-axes m, angle deg clockwise from north),
    a moving transmitter's course and speed as a track, the state and warnings in the remarks, stale `stale_s` from
    now."""
    pytak = _pytak()
    ident = xml_text(name or est.channel)
    major, minor, azimuth = ellipse_axes(est.cov if est.ground_cov is None else est.ground_cov)
    shape = ET.Element("shape")
    ET.SubElement(shape, "ellipse", major=f"{major:.1f}", minor=f"{minor:.1f}", angle=f"{azimuth:.1f}")
    frequency = "" if math.isnan(est.frequency_hz) else f" ({est.frequency_hz / 1e6:.3f} MHz)"
    detail = pytak.cot_detail(shape)
    if est.motion == "moving" and est.velocity is not None:  # CoT's track: course deg clockwise from north, m/s
        east, north = (float(v) for v in est.velocity)
        ET.SubElement(detail, "track", course=f"{math.degrees(math.atan2(east, north)) % 360.0:.1f}",
                      speed=f"{math.hypot(east, north):.2f}")
    pytak.add_remarks(detail, [f"aoa_localizer {ident}{frequency}: {est.state};",
                               f"95 % ellipse {major:.0f} x {minor:.0f} m ({ELLIPSE_95:.2f} sigma^2);",
                               f"{est.bearings_used} bearings.", *map(xml_text, est.warnings)])
    ground = est.cov if est.ground_cov is None else est.ground_cov
    # CoT's ce is CE90 (the circle holding 90 %; ATAK's CotPoint), le LE90 of the height, which is not estimated:
    # CoT's 9999999 for "unknown", as hae
    point = pytak.cot_point(est.lat, est.lon, ce=f"{circular_error(ground, 0.9):.1f}", hae=None, le=None, precision=7)
    event = pytak.cot_event(uid=f"{UID_PREFIX}.{ident}", stale=max(1, round(stale_s)), cot_type=COT_TYPE,
                            point=point, detail=detail, callsign=f"DF {ident}")
    return pytak.serialize_cot(event)


FILE_STALE_S = 3600.0  # a .cot file's event stays fresh this long after it is written


def write_cot_files(folder, estimates, stale_s: float = FILE_STALE_S) -> str:
    """`emitter_<name>.cot` in `folder` for each estimate (named by its channel, or a survey's id, as
    output.file_names names it: one file per id), to drop onto a TAK device or send with any CoT tool; what was
    written, or why nothing was (pytak missing)."""
    try:
        events = [(est.channel, estimate_event(est, stale_s)) for est in estimates]
    except CotUnavailable as exc:
        return f"no .cot files: {exc}"
    names = file_names(name for name, _ in events)
    for name, payload in events:
        (Path(folder) / f"emitter_{names[name]}.cot").write_bytes(payload)
    return f"{len(events)} .cot file{'s' if len(events) != 1 else ''} for TAK"


QUEUE_MAX = 64  # events waiting for the sender's thread; more: the oldest are dropped (counted)
TIMEOUT_S = 2.0  # a TCP connect or send may take this long, on the sender's own thread


def parse_cot_url(url: str) -> tuple[bool, str, int]:
    """(tcp, host, port) of `udp://HOST:PORT` or `tcp://HOST:PORT` (HOST a name, an IPv4 address or an IPv6 one
    in brackets); a ValueError naming what cannot work: another scheme, no host, no port or one outside 1-65535,
    credentials, a path."""
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise ValueError(f"cot_url {url!r}: {exc}") from None
    if parts.scheme not in ("udp", "tcp"):
        raise ValueError(f"cot_url {url!r}: the scheme must be udp:// or tcp:// (pytak's convention)")
    if parts.username is not None or parts.password is not None:
        raise ValueError(f"cot_url {url!r}: credentials are not supported (TAK's UDP and TCP inputs take none)")
    if not parts.hostname:
        raise ValueError(f"cot_url {url!r}: no host")
    if port is None or not 0 < port <= 65535:
        raise ValueError(f"cot_url {url!r}: a port in 1-65535 is needed (udp://HOST:PORT)")
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        raise ValueError(f"cot_url {url!r}: a path, query or fragment means nothing to a CoT input")
    return parts.scheme == "tcp", parts.hostname, port


class CotSender:
    """Sends CoT events to one URL from a thread of its own: `send` only queues (at most QUEUE_MAX, the oldest
    dropped and counted), so a TAK server that is slow, down or never reads costs the caller nothing. A failure is
    counted and kept (`last_error`), never raised; a TCP connection is made again RETRY_S after a failure."""

    def __init__(self, url: str):
        """ValueError for a URL this sender cannot take (parse_cot_url); CotUnavailable without pytak."""
        _pytak()  # the events need it: said at start, not at the first estimate
        self.tcp, self.host, self.port = parse_cot_url(url)
        self.url = url
        self.sent = self.failed = self.dropped = 0
        self.last_error = ""
        self.failing = False  # the last try failed: stays so until an event is sent
        self._sock: socket.socket | None = None
        self._retry_at = 0.0  # monotonic s: no try before (RETRY_S after a failure)
        self._queue: deque[bytes] = deque()
        self._wake = threading.Condition()
        self._closed = self._busy = False
        self._thread = threading.Thread(target=self._run, name="cot_sender", daemon=True)
        self._thread.start()

    def send(self, payload: bytes) -> None:
        """Queue an event for the sender's thread (never blocks, never raises)."""
        with self._wake:
            if self._closed:
                return
            if len(self._queue) >= QUEUE_MAX:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(payload)
            self._wake.notify()

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until every queued event was tried (True), or `timeout` s passed (False)."""
        end = time.monotonic() + timeout
        with self._wake:
            while self._queue or self._busy:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._wake.wait(left)
        return True

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._queue and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                payload = self._queue.popleft()
                self._busy = True
            try:
                self._send_now(payload)
            finally:
                with self._wake:
                    self._busy = False
                    self._wake.notify_all()

    def _send_now(self, payload: bytes) -> None:
        if time.monotonic() < self._retry_at:
            self._failed()
            return
        try:
            if self._sock is None:
                self._sock = self._connect()
            if self.tcp:
                self._sock.sendall(payload + b"\n")
            else:
                self._sock.sendto(payload, (self.host, self.port))
        except Exception as exc:  # noqa: BLE001 - whatever the network says, the localizer goes on
            self._failed()
            self.last_error = f"{type(exc).__name__}: {exc}"
            self._retry_at = time.monotonic() + RETRY_S
            self._close_socket()
            return
        self.sent += 1
        self.failing = False

    def _failed(self) -> None:
        """An event not sent (tried and failed, or within RETRY_S of a failure): counted, and failing until one is."""
        self.failed += 1
        self.failing = True

    def _connect(self) -> socket.socket:
        if self.tcp:
            return socket.create_connection((self.host, self.port), timeout=TIMEOUT_S)
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        sock.settimeout(TIMEOUT_S)
        if family == socket.AF_INET:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)  # multicast stays on the local network
        else:
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, 1)
        return sock

    def _close_socket(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def close(self) -> None:
        """Stop the thread (what is still queued is dropped) and close the socket."""
        with self._wake:
            self._closed = True
            self._wake.notify_all()
        self._thread.join(TIMEOUT_S + 1.0)
        self._close_socket()
