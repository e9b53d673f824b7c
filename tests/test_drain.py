"""The DF subscription's drain (ros/node.py Drain): records queued behind the one the executor took are handled in
the same callback, in order, at most DRAIN_MAX of them, each after the station's queued fixes, and a destroyed
subscription ends it quietly."""
from rclpy.exceptions import InvalidHandle

from aoa_localizer.ros.node import DRAIN_MAX, FIRST_EVERY, Drain


class FakeHandle:
    def __init__(self, queue, fail_after=None):
        self.queue, self.fail_after, self.takes = queue, fail_after, 0

    def __enter__(self):
        if self.fail_after is not None and self.takes >= self.fail_after:
            raise InvalidHandle("destroyed")
        return self

    def __exit__(self, *exc):
        return False

    def take_message(self, msg_type, raw):
        assert raw is False
        self.takes += 1
        return self.queue.pop(0) if self.queue else None


class FakeSubscription:
    msg_type, raw = "Vector3Stamped", False

    def __init__(self, queue, fail_after=None):
        self.handle = FakeHandle(queue, fail_after)


def drained(queue, fail_after=None):
    handled = []
    drain = Drain(lambda msg, info: handled.append((msg, info)))
    drain.subscription = FakeSubscription(queue, fail_after)
    drain("first", {"received_timestamp": 1})
    return handled


def test_the_queued_records_are_handled_in_order_with_their_own_info():
    assert drained([("b", {"t": 2}), ("c", {"t": 3})]) == [("first", {"received_timestamp": 1}), ("b", {"t": 2}),
                                                          ("c", {"t": 3})]


def test_at_most_drain_max_more_then_the_executor_gets_its_turn():
    queue = [(i, {}) for i in range(DRAIN_MAX + 5)]
    assert len(drained(queue)) == 1 + DRAIN_MAX
    assert len(queue) == 5  # left for the next callback


def test_a_subscription_destroyed_meanwhile_ends_the_drain():
    assert [m for m, _ in drained([("b", {}), ("c", {})], fail_after=1)] == ["first", "b"]


def test_the_fixes_queued_beside_the_records_are_handled_first_and_every_few_records():
    """A burst: DF records ahead of the fixes queued beside them would wait for fixes already come and, past 2 x
    gps_max_gap_s, be refused as gps_gap. The fixes queued go before the executor's record and before every
    FIRST_EVERY-th drained one."""
    handled = []
    fixes = [("fix 1", {}), ("fix 2", {})]
    records = [(f"r{k}", {}) for k in range(1, 2 * FIRST_EVERY + 1)]

    def on_record(msg, info):
        handled.append(msg)
        if msg in ("a", f"r{FIRST_EVERY - 1}"):
            fixes.append((f"fix after {msg}", {}))  # a fix arrives while the drain runs

    def on_fix(msg, info):
        handled.append(msg)
        if msg == "fix 2":
            fixes.append(("fix 3", {}))  # came while fix 2 was handled: the queue is emptied, so it goes first too

    drain = Drain(on_record)
    drain.subscription = FakeSubscription(records)
    drain.first = (FakeSubscription(fixes), on_fix)
    drain("a", {})
    rest = [f"r{k}" for k in range(1, 2 * FIRST_EVERY + 1)]
    assert handled == (["fix 1", "fix 2", "fix 3", "a"] + rest[:FIRST_EVERY - 1]
                       + ["fix after a", f"fix after r{FIRST_EVERY - 1}"] + rest[FIRST_EVERY - 1:])


def test_a_fix_subscription_destroyed_meanwhile_ends_the_drain():
    handled = []
    drain = Drain(lambda msg, info: handled.append(msg))
    drain.subscription = FakeSubscription([("b", {})])
    drain.first = (FakeSubscription([("fix", {})], fail_after=0), lambda msg, info: handled.append(msg))
    drain("a", {})
    assert handled == []
