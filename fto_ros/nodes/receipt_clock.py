"""When a Float64MultiArray sample was taken: the node clock at its receipt by DDS.

A Float64MultiArray has no stamp, so the node stamps it with its clock *at its receipt
by DDS* (the ``received_timestamp`` of its message info), not when the executor gets
round to it: a node running behind its input still sees the true sample spacing.  With
wall time that is the receipt time itself; under ``use_sim_time`` it is the last
``/clock`` received before the message.  rclpy's own /clock subscription keeps only the
latest message, so a node lagging a 1 kHz bag would stamp a backlog of samples with one
(later) time: ``ReceiptClock`` replaces it (same callback, deeper queue, drained before
every stamp).  It also tells "ROS time 0 = no /clock yet" from a bag that starts at 0.
"""
from __future__ import annotations

import time
from collections import deque

from rclpy.exceptions import InvalidHandle
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as RosClock

_NS = 1_000_000_000


class ReceiptClock:
    """The node clock at a message's receipt; see the module docstring."""

    def __init__(self, node):
        self.node = node
        self.clock = node.get_clock()
        self._hist: deque[tuple[int, int]] = deque(maxlen=4096)  # (received ns, clock ns)
        self._seen = not self.clock.ros_time_is_active
        self._sub = None
        self._time_source_cb = None
        if not self.clock.ros_time_is_active:
            return
        ts = getattr(node, "_time_source", None)
        old = getattr(ts, "_clock_sub", None)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT,
                         history=HistoryPolicy.KEEP_LAST)
        if old is not None and callable(getattr(ts, "clock_callback", None)):
            node.destroy_subscription(old)
            self._time_source_cb = ts.clock_callback
            self._sub = ts._clock_sub = node.create_subscription(RosClock, "/clock", self._on_clock, qos)
        else:  # another rclpy: keep its subscription, add ours next to it
            self._sub = node.create_subscription(RosClock, "/clock", self._on_clock, qos)

    def _on_clock(self, msg, info) -> None:
        if self._time_source_cb is not None:
            self._time_source_cb(msg)  # sets the node clock (and fires the jump callbacks)
        self._seen = True
        received = info.get("received_timestamp") or time.time_ns()
        self._hist.append((received, msg.clock.sec * _NS + msg.clock.nanosec))

    def _drain(self) -> None:
        """Take every /clock message already received (the executor may lag behind DDS)."""
        sub = self._sub
        try:
            with sub.handle:
                while True:
                    got = sub.handle.take_message(RosClock, False)
                    if got is None:
                        return
                    self._on_clock(*got)
        except InvalidHandle:  # use_sim_time switched off at run time
            self._sub = None

    def receipt_ns(self, info) -> int | None:
        """The node clock (ns) when DDS received the message; None: no /clock yet."""
        received = info.get("received_timestamp", 0) if info else 0
        if not self.clock.ros_time_is_active:
            return received if received > 0 else self.clock.now().nanoseconds
        sub = self._sub
        ts = getattr(self.node, "_time_source", None)
        if sub is None or received <= 0 or (self._time_source_cb is not None
                                            and getattr(ts, "_clock_sub", None) is not sub):
            return self.now_ns()
        self._drain()
        for t_received, clock_ns in reversed(self._hist):
            if t_received <= received:
                return clock_ns
        return None

    def now_ns(self) -> int | None:
        """Node clock now in ns; None while sim time is on and no /clock has arrived."""
        ns = self.clock.now().nanoseconds
        if ns == 0 and not self._seen and self.clock.ros_time_is_active:
            return None
        return ns
