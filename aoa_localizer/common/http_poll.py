"""One bounded HTTP GET for the receiver bridges: whatever the server sends (a reply cut short, a status line that
is not HTTP, endless or huge headers, an endless or 1 byte/s body, a redirect elsewhere), it returns the page or
a one-line reason within its deadline and its byte limit, and a stop request ends it within WATCH_S.

Limits (docs/failure_behaviour.md, "Receiver bridges"): `max_bytes` of body (the Kraken App page is a few KiB per
VFO), `deadline_s` for the whole poll (connect, headers and body), headers as Python's http.client bounds them
(64 KiB a line, 100 lines). Redirects are refused with their target: a DF page that moves to another host is a
set-up to look at, not to follow silently."""
from __future__ import annotations

import http.client
import socket
import threading
import time
import urllib.parse
from collections.abc import Callable

WATCH_S = 0.1  # how often the watchdog looks at the deadline and the stop request
CONNECT_MAX_S = 1.5  # a DF receiver is on the vehicle's network: a connect slower than this is an outage
DEFAULT_MAX_BYTES = 4 * 1024 * 1024


class PollFailed(Exception):
    """The poll got no usable page; the message says why in a few words."""


class _Watchdog(threading.Thread):
    """Shuts the connection's socket at the poll's deadline or on a stop request, whatever step is blocked in it
    (http.client reads headers line by line: a server trickling them a byte at a time never times out)."""

    def __init__(self, conn: http.client.HTTPConnection, end: float, stop: Callable[[], bool]):
        super().__init__(daemon=True)
        self.conn, self.end, self.stop = conn, end, stop
        self.sock: socket.socket | None = None  # the response keeps the socket once the connection lets it go
        self.done = threading.Event()
        self.fired: str | None = None

    def run(self):
        while not self.done.wait(WATCH_S):
            if self.stop() or time.monotonic() > self.end:
                self.fired = "stopped" if self.stop() else "deadline"
                sock = self.sock or self.conn.sock
                if sock is not None:
                    try:
                        sock.shutdown(socket.SHUT_RDWR)
                    except OSError:
                        pass
                return


def http_get(url: str, deadline_s: float, max_bytes: int = DEFAULT_MAX_BYTES,
             stop: Callable[[], bool] = lambda: False) -> str:
    """The body of `url` (UTF-8, bad bytes replaced), or PollFailed with the reason."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise PollFailed(f"not an http(s) address: {url!r}")
    cls = http.client.HTTPSConnection if parts.scheme == "https" else http.client.HTTPConnection
    path = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
    try:
        conn = cls(parts.hostname, parts.port, timeout=max(min(deadline_s, CONNECT_MAX_S), 0.01))
    except ValueError as exc:  # a port out of range
        raise PollFailed(str(exc)) from None
    watchdog = _Watchdog(conn, time.monotonic() + deadline_s, stop)
    watchdog.start()
    try:
        page = _get(conn, watchdog, path, max_bytes, deadline_s)
        if watchdog.fired:  # the socket was shut under a body that ends at the connection's close
            raise OSError(watchdog.fired)
        return page
    except PollFailed:
        raise
    except (http.client.HTTPException, OSError, ValueError) as exc:
        if watchdog.fired == "deadline" or isinstance(exc, TimeoutError):
            raise PollFailed(f"no complete answer within {deadline_s:g} s") from None
        if watchdog.fired == "stopped":
            raise PollFailed("stopped") from None
        raise PollFailed(f"{type(exc).__name__}: {str(exc)[:200]}") from None
    finally:
        watchdog.done.set()
        conn.close()


def _get(conn: http.client.HTTPConnection, watchdog: _Watchdog, path: str, max_bytes: int, deadline_s: float) -> str:
    conn.request("GET", path, headers={"Connection": "close"})
    watchdog.sock = conn.sock
    if conn.sock is not None:
        conn.sock.settimeout(deadline_s)
    response = conn.getresponse()
    if response.status in (301, 302, 303, 307, 308):
        raise PollFailed(f"redirected to {response.getheader('Location')!r} (not followed: set --url to it)")
    if response.status != 200:
        raise PollFailed(f"HTTP {response.status} {response.reason}")
    body = bytearray()
    while chunk := response.read1(65536):
        body += chunk
        if len(body) > max_bytes:
            raise PollFailed(f"page larger than {max_bytes} bytes")
    if response.length:  # a Content-Length the body fell short of
        raise PollFailed(f"reply cut short: {response.length} bytes missing")
    return body.decode("utf-8", errors="replace")
