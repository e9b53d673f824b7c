"""A local HTTP server that answers each path with one hostile reply (the reliability review's attacks on the
KrakenSDR bridge). Loopback only; every reply is bounded in bytes and time and stops when the client goes."""
from __future__ import annotations

import socketserver
import threading
import time

GOOD = b"1700000000000,90,8,-40,433920000,UCA,500,k1,39.1,117.2,0,0,GPS,R,R,R,R\n"
SEND_MAX_BYTES = 64 * 1024 * 1024
SEND_MAX_S = 20.0


def _ok(body: bytes, extra: str = "") -> bytes:
    return f"HTTP/1.0 200 OK\r\nContent-Length: {len(body)}\r\n{extra}\r\n".encode() + body


REPLIES = {
    "/good": lambda: [_ok(GOOD)],
    "/cut": lambda: [b"HTTP/1.0 200 OK\r\nContent-Length: 5000\r\n\r\n" + GOOD],  # then the server is gone
    "/not_http": lambda: [b"SSH-2.0-OpenSSH_9.6\r\n\r\n"],
    "/long_header": lambda: [b"HTTP/1.0 200 OK\r\nX-Big: " + b"a" * 70_000 + b"\r\n\r\n" + GOOD],
    "/many_headers": lambda: [b"HTTP/1.0 200 OK\r\n" + b"".join(b"X-%d: 1\r\n" % k for k in range(150)) + b"\r\n"],
    "/redirect": lambda: [b"HTTP/1.0 302 Found\r\nLocation: http://127.0.0.1:1/elsewhere\r\n\r\n"],
    "/status_500": lambda: [b"HTTP/1.0 500 Internal Server Error\r\nContent-Length: 0\r\n\r\n"],
}


class _Handler(socketserver.BaseRequestHandler):
    def handle(self):
        self.server.requests += 1  # type: ignore[attr-defined]  # HostileServer's count
        request = self.request.recv(4096).decode("latin-1")
        path = request.split(" ")[1] if request.count(" ") >= 2 else "/"
        start, sent = time.monotonic(), 0
        try:
            if path in REPLIES:
                for part in REPLIES[path]():
                    self.request.sendall(part)
            elif path == "/endless":  # a body with no end, as fast as the client reads
                self.request.sendall(b"HTTP/1.0 200 OK\r\n\r\n")
                chunk = GOOD * 1000
                while sent < SEND_MAX_BYTES and time.monotonic() - start < SEND_MAX_S:
                    self.request.sendall(chunk)
                    sent += len(chunk)
            elif path in ("/trickle_body", "/trickle_headers"):  # a byte at a time, 20 a second
                head = b"HTTP/1.0 200 OK\r\n" + (b"" if path == "/trickle_headers" else b"\r\n")
                self.request.sendall(head)
                while time.monotonic() - start < SEND_MAX_S:
                    self.request.sendall(b"a" if path == "/trickle_body" else b"X")
                    time.sleep(0.05)
        except OSError:  # the client went: what it should do
            pass


class HostileServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self):
        super().__init__(("127.0.0.1", 0), _Handler)
        self.requests = 0  # requests taken so far: a test waits on it, never on a fixed sleep
        self.thread = threading.Thread(target=self.serve_forever, daemon=True)

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}{path}"

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.shutdown()
        self.server_close()
