"""The DF subscription's drain (ros/node.py Drain): records queued behind the one the executor took are handled in
the same callback, in order, at most DRAIN_MAX of them, and a destroyed subscription ends it quietly."""
from rclpy.exceptions import InvalidHandle

from aoa_localizer.ros.node import DRAIN_MAX, Drain


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
        assert (msg_type, raw) == ("Vector3Stamped", False)
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
