"""Cursor-on-Target for TAK (ATAK, WinTAK, iTAK): an emitter estimate as a CoT event, encoded by pytak (an
optional extra, `pip install 'aoa_localizer[tak]'`), and a sender for pytak's URL convention (`udp://host:port`,
unicast, broadcast or multicast such as udp://239.2.3.1:6969; `tcp://host:port`). The event is the emitter's point
with the 95 % ellipse as its circular error and as a CoT ellipse shape, the state and the ellipse in the remarks,
and a stale time after which TAK greys it out (docs/interface.md, "TAK")."""
from __future__ import annotations

import math
import socket
import time
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path
from urllib.parse import urlparse

from aoa_localizer.common.output import file_names
from aoa_localizer.common.xml_text import xml_text
from aoa_localizer.engine.crlb import ELLIPSE_95, ellipse_axes

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
    the 95 % ellipse's semi-major (m), a shape with the 95 % ellipse (semi-axes m, angle deg clockwise from north),
    the state and warnings in the remarks, stale `stale_s` from now."""
    pytak = _pytak()
    ident = xml_text(name or est.channel)
    major, minor, azimuth = ellipse_axes(est.cov if est.ground_cov is None else est.ground_cov)
    shape = ET.Element("shape")
    ET.SubElement(shape, "ellipse", major=f"{major:.1f}", minor=f"{minor:.1f}", angle=f"{azimuth:.1f}")
    frequency = "" if math.isnan(est.frequency_hz) else f" ({est.frequency_hz / 1e6:.3f} MHz)"
    detail = pytak.cot_detail(shape)
    pytak.add_remarks(detail, [f"aoa_localizer {ident}{frequency}: {est.state};",
                               f"95 % ellipse {major:.0f} x {minor:.0f} m ({ELLIPSE_95:.2f} sigma^2);",
                               f"{est.bearings_used} bearings.", *map(xml_text, est.warnings)])
    point = pytak.cot_point(est.lat, est.lon, ce=f"{major:.1f}", hae=None, le=None, precision=7)
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


class CotSender:
    """Sends CoT events to one URL; a failure to send is counted and kept (`last_error`), never raised: a TAK
    server that is down must not stop the localizer. A TCP connection is made again at the next event."""

    def __init__(self, url: str):
        """ValueError for a URL this sender cannot take (its scheme or its host and port)."""
        pytak = _pytak()
        parsed = urlparse(url)
        scheme, _, read_only = pytak.parse_cot_scheme(parsed.scheme)
        if scheme not in ("udp", "tcp") or read_only:
            raise ValueError(f"cot_url {url!r}: the scheme must be udp:// or tcp:// (pytak's convention)")
        try:
            self.host, self.port = pytak.parse_url(parsed)
        except (ValueError, AssertionError) as exc:
            raise ValueError(f"cot_url {url!r}: no host:port ({exc})") from exc
        if not self.host:
            raise ValueError(f"cot_url {url!r}: no host")
        self.url, self.tcp = url, scheme == "tcp"
        self.sent = self.failed = 0
        self.last_error = ""
        self._sock: socket.socket | None = None
        self._retry_at = 0.0  # monotonic s: no try before (RETRY_S after a failure)

    def send(self, payload: bytes) -> bool:
        """True when the event went out (False, counted: it failed, or the last failure is under RETRY_S old)."""
        if time.monotonic() < self._retry_at:
            self.failed += 1
            return False
        try:
            if self._sock is None:
                self._sock = self._connect()
            if self.tcp:
                self._sock.sendall(payload + b"\n")
            else:
                self._sock.sendto(payload, (self.host, self.port))
        except OSError as exc:
            self.failed += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            self._retry_at = time.monotonic() + RETRY_S
            self.close()
            return False
        self.sent += 1
        return True

    def _connect(self) -> socket.socket:
        if self.tcp:
            return socket.create_connection((self.host, self.port), timeout=2.0)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)  # multicast stays on the local network
        return sock

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
