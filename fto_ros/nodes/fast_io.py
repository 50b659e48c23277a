"""JointState in and out at 1 kHz for little CPU: the executor, a raw intake, a raw publisher.

Measured in ``benchmarks/bench_node_io.py`` (docs/benchmarks.md, "JointState I/O of the
node"); what this module offers is what won there:

- :func:`create_executor` and :func:`spin`: rclpy's ``EventsExecutor``
  (``rclpy.experimental``, C++: no wait set rebuilt per message) or the
  ``SingleThreadedExecutor``.  Three traps of the EventsExecutor in rclpy 7.1.6: its
  ``spin()`` runs nothing (:func:`spin` loops on ``spin_once``); it calls a callback
  that takes message info with ONE argument, the tuple ``(msg, info)``, and fails
  inside the executor (``SystemError``): :func:`message_info_callback` wraps such a
  callback for both executors; it supports no guard conditions (neither the observer
  node nor rclpy's Node create any).
- :class:`JointStateIntake`: a raw (serialised) subscription decoded with numpy
  (``core/cdr.py``): per message, or every message waiting in the
  subscription in one call (``on_block``).  A payload the decoder does not take (big
  endian, XCDR2, ...) goes through rclpy's deserialiser, the reference; one that fails
  there too is counted in ``rejected`` and handed to ``on_reject`` with the reason, never
  raised into the executor.
- :class:`JointStatePublisher`: publishes pre-serialised CDR bytes filled from numpy
  arrays into one reused buffer (names, frame_id and array lengths fixed).
"""
from __future__ import annotations

import inspect
from typing import Callable

import numpy as np
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from ..core.cdr import JointStateArrays, JointStateDecoder, JointStateEncoder, stamp_ns
from ..core.errors import BadArgument, DecodeError
from ..runner.sources.base import from_message
from .publisher import OUT_QOS

EXECUTORS = ("events", "single")


def create_executor(kind: str = "events", context=None):
    """An executor for the node: ``"events"`` (rclpy.experimental.EventsExecutor) or
    ``"single"`` (SingleThreadedExecutor).  Spin it with :func:`spin`."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == "single":
        return SingleThreadedExecutor(context=context)
    raise BadArgument(f"executor must be one of {EXECUTORS}, got {kind!r}")


def spin(executor, poll_s: float = 0.5) -> None:
    """Run the executor's callbacks until its context shuts down (Ctrl-C included), then
    return (KeyboardInterrupt aside, as rclpy's own spin).

    The EventsExecutor's own ``spin()`` (rclpy 7.1.6 wheels) runs no callback, burns
    CPU and ignores SIGINT; ``spin_once(timeout)`` in a loop works: this is that loop.
    """
    try:
        if isinstance(executor, SingleThreadedExecutor):
            executor.spin()
            return
        context = executor.context
        while context.ok():
            executor.spin_once(timeout_sec=poll_s)
    except ExternalShutdownException:
        return


class message_info_callback:  # noqa: N801 (used like a decorator)
    """``fn(msg, info)`` as a subscription callback that works under both executors.

    rclpy detects a callback that wants the message info from its signature (two
    parameters); the SingleThreadedExecutor then calls ``cb(msg, info)``, the
    EventsExecutor of rclpy 7.1.6 ``cb((msg, info))``.  This object declares the
    two-parameter signature and accepts both calls."""

    __signature__ = inspect.Signature([
        inspect.Parameter("msg", inspect.Parameter.POSITIONAL_ONLY),
        inspect.Parameter("info", inspect.Parameter.POSITIONAL_ONLY)])

    def __init__(self, fn: Callable):
        self.fn = fn

    def __call__(self, *args):
        if len(args) == 1:      # the EventsExecutor's single tuple
            args = args[0]
        return self.fn(*args)


def decode_payload(decoder: JointStateDecoder, payload: bytes
                   ) -> tuple[JointStateArrays | None, str]:
    """One serialised JointState: ``(arrays, "numpy")`` by ``decoder``, ``(arrays, "rclpy")``
    by rclpy's deserialiser (a payload the numpy decoder does not take), or ``(None,
    reason)`` when neither takes it (``undecodable_joint_state: <error type>``)."""
    try:
        return decoder.decode(payload), "numpy"
    except DecodeError:
        pass
    try:
        msg = deserialize_message(payload, JointState)
    except Exception as exc:  # rclpy raises RuntimeError / its own types; never into the executor
        return None, f"undecodable_joint_state: {type(exc).__name__}"
    return from_message(msg), "rclpy"


class JointStateIntake:
    """A raw JointState subscription handing numpy arrays; see the module docstring.

    ``on_message(js)``: called once per message with a
    :class:`~fto_ros.core.cdr.JointStateArrays` (stamp, frame_id, names,
    read-only float64 arrays).  Or ``on_block(runs)`` instead, once per
    executor callback with every message waiting then: ``runs`` is a list of
    ``(stamps_ns, js)`` where consecutive messages of one layout (names, lengths) share
    one ``js`` with (k, n) arrays.  ``on_reject(reason)``: a payload nobody can decode.
    The subscription has no QoS event callbacks (as the node's other high-rate entities);
    ``kwargs`` go to ``create_subscription`` (e.g. qos_overriding_options).
    """

    def __init__(self, node, topic: str, qos, on_message: Callable | None = None, *,
                 on_block: Callable | None = None,
                 on_reject: Callable[[str], None] | None = None, **kwargs):
        if (on_message is None) == (on_block is None):
            raise BadArgument("give one of on_message (per message) and on_block (every message waiting)")
        self._on_message, self._on_block = on_message, on_block
        self._on_reject = on_reject
        self.decoder = JointStateDecoder()
        self.received = self.fallback = self.rejected = 0
        self.callbacks = 0
        kwargs.setdefault("event_callbacks", SubscriptionEventCallbacks(use_default_callbacks=False))
        self.subscription = node.create_subscription(
            JointState, topic, self._on_payload if on_block is None else self._on_waiting, qos,
            raw=True, **kwargs)

    # ---------------------------------------------------------------- decoding
    def decode(self, payload: bytes) -> JointStateArrays | None:
        """One payload; None (counted, on_reject) when neither decoder takes it."""
        js, how = decode_payload(self.decoder, payload)
        if js is None:
            self._reject(how)
        elif how == "rclpy":
            self.fallback += 1
        return js

    def _reject(self, reason: str) -> None:
        self.rejected += 1
        if self._on_reject is not None:
            self._on_reject(reason)

    def take_waiting(self) -> list[bytes]:
        """Every payload already received and not yet taken (none once destroyed)."""
        out = []
        handle = self.subscription.handle
        try:
            with handle:
                while True:
                    got = handle.take_message(JointState, True)
                    if got is None:
                        return out
                    out.append(got[0])
        except InvalidHandle:
            return out

    # --------------------------------------------------------------- callbacks
    def _on_payload(self, payload: bytes) -> None:
        self.received += 1
        self.callbacks += 1
        js = self.decode(payload)
        if js is not None:
            self._on_message(js)

    def _on_waiting(self, payload: bytes) -> None:
        payloads = [payload]
        payloads += self.take_waiting()
        self.received += len(payloads)
        self.callbacks += 1
        try:
            runs = [(stamp_ns(sec, nsec), js) for sec, nsec, js in self.decoder.decode_block(payloads)]
        except DecodeError:   # one odd payload: each on its own (fallback, rejection)
            runs = []
            for p in payloads:
                js = self.decode(p)
                if js is not None:
                    runs.append((np.array([js.stamp_ns], dtype=np.int64),
                                 js._replace(position=js.position[None, :],
                                             velocity=js.velocity[None, :],
                                             effort=js.effort[None, :])))
        if runs:
            self._on_block(runs)


class JointStatePublisher:
    """Publish JointStates as pre-serialised CDR from numpy arrays (one buffer reused).

    ``sizes``: lengths of position, velocity, effort (default one per name each; 0
    publishes that array empty).  Reliable keep-last 10 (the node's output QoS) unless
    ``qos`` is given; no QoS event callbacks.
    """

    def __init__(self, node, topic: str, names, sizes=None, frame_id: str = "", qos=None):
        self.encoder = JointStateEncoder(names, sizes, frame_id)
        self.publisher = node.create_publisher(
            JointState, topic, OUT_QOS if qos is None else qos,
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
        self._publish = self.publisher.publish

    def publish(self, sec: int, nanosec: int, position, velocity=None, effort=None) -> None:
        """One message: ``(sec, nanosec)`` the stamp, the arrays of the layout's lengths
        (None for an empty one); ValueError for other lengths or a stamp out of range."""
        self._publish(self.encoder.encode(sec, nanosec, position, velocity, effort))

    def get_subscription_count(self) -> int:
        return self.publisher.get_subscription_count()
