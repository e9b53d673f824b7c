"""A TAK client from PyPI as the receiving end of the node's Cursor-on-Target: pytak's own UDP reader and
RXWorker (what pytak-based gateways and TAK tools use to take CoT off the wire), run in a thread of its own."""
from __future__ import annotations

import asyncio
import socket
import threading
import warnings

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # pytak warns that its optional TLS and HTTP extras are not installed
    import pytak


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nobody holds (pytak binds the port it is given)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Collect(pytak.RXWorker):
    """pytak's receive worker, each event it reads kept as bytes."""

    def __init__(self, config: dict, reader, into: list) -> None:
        super().__init__(asyncio.Queue(), config, reader)
        self.into = into

    async def handle_data(self, data: bytes) -> None:
        self.into.append(bytes(data))

    async def put_queue(self, data: bytes, queue_arg=None) -> None:  # what pytak's run_once does with an event read
        await self.handle_data(data)


class PytakListener:
    """`with PytakListener() as tak:` pytak reads CoT on `tak.url`'s port; `tak.events` holds what it read."""

    def __init__(self) -> None:
        self.port = free_udp_port()
        self.url = f"udp://127.0.0.1:{self.port}"
        self.events: list[bytes] = []
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.error: BaseException | None = None

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._serve())
        except asyncio.CancelledError:
            pass
        except BaseException as exc:  # noqa: BLE001 - handed to the test, which fails on it
            self.error = exc
            self._ready.set()

    async def _serve(self) -> None:
        config = {"COT_URL": f"udp+ro://127.0.0.1:{self.port}"}
        reader, _ = await pytak.protocol_factory(config)
        worker = _Collect(config, reader, self.events)
        self._ready.set()
        await worker.run()

    def __enter__(self) -> PytakListener:
        self._thread.start()
        if not self._ready.wait(10) or self.error is not None:
            raise RuntimeError(f"pytak's reader did not start: {self.error!r}")
        return self

    def __exit__(self, *exc) -> None:
        for task in asyncio.all_tasks(self._loop):
            self._loop.call_soon_threadsafe(task.cancel)
        self._thread.join(5)
