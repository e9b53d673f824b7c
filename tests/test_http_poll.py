"""The bridges' HTTP poll against a hostile local server: every reply ends in the page or a reason, within the
poll's deadline and byte limit, and a stop request ends it at once (reliability III, items 3 and 4)."""
import time

import pytest
from hostile_http import GOOD, HostileServer

from aoa_localizer.common.http_poll import WATCH_S, PollFailed, http_get

BUSY_S = 2.0  # what a machine busy with other work may add to a deadline kept by a watchdog thread


@pytest.fixture(scope="module")
def server():
    with HostileServer() as s:
        yield s


def test_a_good_page_is_returned(server):
    assert http_get(server.url("/good"), 2.0) == GOOD.decode()


@pytest.mark.parametrize(("path", "words"), [
    ("/cut", "cut short"),
    ("/not_http", "BadStatusLine"),
    ("/long_header", "LineTooLong"),
    ("/many_headers", "more than 100 headers"),
    ("/redirect", "redirected to 'http://127.0.0.1:1/elsewhere'"),
    ("/status_500", "HTTP 500"),
    pytest.param("/endless", "larger than 100000 bytes", marks=pytest.mark.slow),  # the server streams until cut
    pytest.param("/trickle_body", "within 1 s", marks=pytest.mark.slow),  # a second each: the deadline
    pytest.param("/trickle_headers", "within 1 s", marks=pytest.mark.slow),
])
def test_each_hostile_reply_is_a_reason_within_the_deadline(server, path, words):
    start = time.monotonic()
    with pytest.raises(PollFailed, match=words.replace("(", r"\(").replace(")", r"\)")):
        http_get(server.url(path), 1.0, max_bytes=100_000)
    assert time.monotonic() - start < 1.0 + 3 * WATCH_S + BUSY_S


@pytest.mark.slow
def test_a_stop_request_ends_a_poll_at_once(server):
    start = time.monotonic()
    with pytest.raises(PollFailed, match="stopped"):
        http_get(server.url("/trickle_headers"), 30.0, stop=lambda: time.monotonic() - start > 0.3)
    assert time.monotonic() - start < 0.3 + 3 * WATCH_S + BUSY_S


@pytest.mark.slow
def test_nothing_listening_and_bad_addresses_are_reasons():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for url in (f"http://127.0.0.1:{port}/x", "http://127.0.0.1:99999/x", "ftp://host/x", "http:///x"):
        with pytest.raises(PollFailed):
            http_get(url, 1.0)
