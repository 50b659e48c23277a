"""nodes/fast_io.py over DDS: the raw JointState intake equals rclpy's deserialisation field
by field, the raw publisher's messages read back as the values given, under both executors.

One process, one rclpy context per test (LOCALHOST discovery, a domain id of the test's
own: test/support/domains.py); the messages go through Fast DDS as between processes.
"""
from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

import domains  # noqa: E402

from fto_ros.nodes.fast_io import (EXECUTORS, JointStateIntake, JointStatePublisher,  # noqa: E402
                                   create_executor, message_info_callback, spin)

#: live DDS: scripts/run-tests runs these after the rest, one at a time
pytestmark = pytest.mark.live

QOS = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
ARM = [f"joint_a{i}" for i in range(1, 8)]


@pytest.fixture
def ros():
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domains.take())
    node = rclpy.create_node("fast_io_test", context=ctx)
    yield ctx, node
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def _spin_until(ex, cond, timeout=15.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end and not cond():
        ex.spin_once(timeout_sec=0.02)
    return cond()


def _wait_matched(ex, pub, subs: int = 1) -> None:
    assert _spin_until(ex, lambda: pub.get_subscription_count() >= subs, 10.0), "no match"


def _msg(names, pos, vel, eff, sec, nanosec=0, frame_id=""):
    m = JointState(name=list(names), position=list(map(float, pos)), velocity=list(map(float, vel)),
                   effort=list(map(float, eff)))
    m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
    m.header.frame_id = frame_id
    return m


def _stream():
    """A 7-joint stream with the odd ones a real topic carries: velocity empty, arrays
    shorter than name, another publisher's layout (a gripper), a frame_id, stamp extremes."""
    out = []
    for k in range(40):
        v = np.arange(7) * 0.1 + k
        out.append(_msg(ARM, v, -v, 2 * v, sec=1_700_000_000 + k, nanosec=1000 * k))
    out[5] = _msg(ARM, range(7), [], range(7), sec=5)                        # no velocity
    out[9] = _msg(ARM, [1.0, 2.0], [3.0], [], sec=9, frame_id="base_link")   # shorter than name
    out[10] = _msg(["gripper_left", "gripper_right"], [0.01, 0.02], [0, 0], [1, 1], sec=10)
    out[11] = _msg([], [], [], [], sec=-2**31, nanosec=2**32 - 1)
    out[12] = _msg(ARM[::-1], range(7), range(7), range(7), sec=2**31 - 1)   # reordered
    out[13] = _msg(["épaule"], [np.nan], [np.inf], [-0.0], sec=13)
    return out


def _assert_equal(js, ref: JointState) -> None:
    assert (js.sec, js.nanosec) == (ref.header.stamp.sec, ref.header.stamp.nanosec)
    assert js.frame_id == ref.header.frame_id and list(js.name) == list(ref.name)
    for f in ("position", "velocity", "effort"):
        got, want = getattr(js, f), np.array(getattr(ref, f), dtype=np.float64)
        assert got.shape == want.shape and np.array_equal(got, want, equal_nan=True), f


@pytest.mark.parametrize("kind", EXECUTORS)
def test_intake_equals_rclpy_deserialisation_live(ros, kind):
    ctx, node = ros
    decoded, reference = [], []
    intake = JointStateIntake(node, "js_in", QOS, on_message=decoded.append)
    node.create_subscription(JointState, "js_in", reference.append, QOS)
    pub = node.create_publisher(JointState, "js_in", QOS)
    ex = create_executor(kind, context=ctx)
    ex.add_node(node)
    _wait_matched(ex, pub, 2)
    stream = _stream()
    for m in stream:
        pub.publish(m)
        ex.spin_once(timeout_sec=0.001)
    assert _spin_until(ex, lambda: len(decoded) >= len(stream) and len(reference) >= len(stream))
    assert len(decoded) == len(reference) == len(stream)
    for js, ref, sent in zip(decoded, reference, stream):
        _assert_equal(js, ref)
        _assert_equal(js, sent)
    assert intake.received == len(stream) and intake.rejected == 0 and intake.fallback == 0
    assert intake.decoder.fast >= 25      # the 7-joint layout repeats: decoded without a parse
    ex.shutdown()


@pytest.mark.parametrize("kind", EXECUTORS)
def test_block_intake_takes_every_waiting_message_in_one_callback_live(ros, kind):
    ctx, node = ros
    blocks = []
    intake = JointStateIntake(node, "js_block", QOS, on_block=blocks.append)
    pub = node.create_publisher(JointState, "js_block", QOS)
    ex = create_executor(kind, context=ctx)
    ex.add_node(node)
    _wait_matched(ex, pub)
    stream = _stream()
    for m in stream:          # all of them wait in the subscription before the executor runs
        pub.publish(m)
    time.sleep(0.5)
    assert _spin_until(ex, lambda: intake.received >= len(stream))
    flat = []
    for runs in blocks:
        for stamps, js in runs:
            assert js.position.shape[0] == len(stamps)
            for i in range(len(stamps)):
                flat.append((int(stamps[i]), js.name, js.frame_id, js.position[i], js.velocity[i],
                             js.effort[i]))
    assert len(flat) == len(stream)
    for (ns, name, frame, p, v, e), m in zip(flat, stream):
        st = m.header.stamp
        assert ns == st.sec * 1_000_000_000 + st.nanosec
        assert list(name) == list(m.name) and frame == m.header.frame_id
        for got, want in ((p, m.position), (v, m.velocity), (e, m.effort)):
            assert np.array_equal(got, np.array(want, dtype=np.float64), equal_nan=True)
    # one callback per message would be 40; taking what waits, a few at most
    assert intake.callbacks <= 5, intake.callbacks
    ex.shutdown()


@pytest.mark.parametrize("kind", EXECUTORS)
def test_publisher_messages_read_back_as_the_values_given_live(ros, kind):
    ctx, node = ros
    full, no_vel = [], []
    node.create_subscription(JointState, "est_full", full.append, QOS)
    node.create_subscription(JointState, "est_no_vel", no_vel.append, QOS)
    pub_full = JointStatePublisher(node, "est_full", ARM, frame_id="world", qos=QOS)
    pub_part = JointStatePublisher(node, "est_no_vel", ARM, sizes=(7, 0, 7))
    ex = create_executor(kind, context=ctx)
    ex.add_node(node)
    _wait_matched(ex, pub_full)
    _wait_matched(ex, pub_part)
    rng = np.random.default_rng(1)
    sent = []
    for k in range(30):
        p, v, e = rng.normal(size=(3, 7))
        sent.append((1_700_000_000 + k, 999_999_999 - k, p, v, e))
        pub_full.publish(1_700_000_000 + k, 999_999_999 - k, p, v, e)
        pub_part.publish(1_700_000_000 + k, 999_999_999 - k, p, None, e)
        ex.spin_once(timeout_sec=0.001)
    assert _spin_until(ex, lambda: len(full) >= 30 and len(no_vel) >= 30)
    for got_full, got_part, (sec, nsec, p, v, e) in zip(full, no_vel, sent):
        _assert_equal_values(got_full, sec, nsec, "world", p, v, e)
        _assert_equal_values(got_part, sec, nsec, "", p, [], e)
    with pytest.raises(ValueError):
        pub_part.publish(0, 0, np.zeros(7), np.zeros(7), np.zeros(7))
    ex.shutdown()


def _assert_equal_values(msg, sec, nsec, frame, p, v, e):
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (sec, nsec)
    assert msg.header.frame_id == frame and list(msg.name) == ARM
    for got, want in ((msg.position, p), (msg.velocity, v), (msg.effort, e)):
        assert np.array_equal(np.array(got), np.asarray(want, dtype=np.float64))


def _big_endian(m: JointState) -> bytes:
    """The message as big-endian CDR (rosbags writes it; Fast DDS on x86 never does)."""
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    st = m.header.stamp
    msg = T["sensor_msgs/msg/JointState"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=st.sec, nanosec=st.nanosec),
                                        frame_id=m.header.frame_id),
        name=list(m.name), position=np.array(m.position), velocity=np.array(m.velocity),
        effort=np.array(m.effort))
    return bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/JointState", little_endian=False))


def test_undecodable_payloads_are_rejected_and_odd_ones_go_through_rclpy_live(ros):
    ctx, node = ros
    decoded, reasons = [], []
    intake = JointStateIntake(node, "js_raw", QOS, on_message=decoded.append, on_reject=reasons.append)
    raw_pub = node.create_publisher(JointState, "js_raw", QOS)
    ex = create_executor("events", context=ctx)
    ex.add_node(node)
    _wait_matched(ex, raw_pub)
    good = serialize_message(_msg(ARM, range(7), range(7), range(7), sec=1))
    big_endian = _big_endian(_msg(ARM, range(7), [], np.arange(7) + 1.5, sec=3, nanosec=4,
                                  frame_id="base"))      # rclpy reads it, our decoder does not
    for payload in (b"\x00\x01\x00\x00" + b"\xff" * 40, good[:30], big_endian, good):
        raw_pub.publish(payload)
    assert _spin_until(ex, lambda: intake.received >= 4)
    assert intake.rejected == 2 and len(reasons) == 2
    assert all(r.startswith("undecodable_joint_state") for r in reasons)
    assert intake.fallback == 1 and len(decoded) == 2
    _assert_equal(decoded[0], deserialize_message(big_endian, JointState))
    _assert_equal(decoded[1], deserialize_message(good, JointState))
    ex.shutdown()


@pytest.mark.parametrize("kind", EXECUTORS)
def test_message_info_callback_and_spin_under_both_executors_live(ros, kind):
    """The info callback gets (msg, info) under both executors; spin() runs callbacks and
    timers (steady clock) and returns when the context shuts down."""
    from rclpy.clock import Clock, ClockType
    ctx, node = ros
    got = []
    node.create_subscription(JointState, "js_info", message_info_callback(lambda m, i: got.append((m, i))),
                             QOS)
    pub = node.create_publisher(JointState, "js_info", QOS)
    ticks = [0]

    def tick():
        ticks[0] += 1
        pub.publish(_msg(ARM, range(7), [], [], sec=ticks[0]))
        if ticks[0] == 20:
            ctx.try_shutdown()
    node.create_timer(0.02, tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
    ex = create_executor(kind, context=ctx)
    ex.add_node(node)
    worker = threading.Thread(target=spin, args=(ex,), kwargs={"poll_s": 0.1}, daemon=True)
    worker.start()
    worker.join(20.0)
    assert not worker.is_alive(), "spin() did not return after the context shut down"
    assert ticks[0] == 20
    assert len(got) >= 10     # the last publishes may not arrive before the shutdown
    for msg, info in got:
        assert isinstance(msg, JointState) and info["received_timestamp"] > 0


def test_intake_and_executor_arguments_are_checked(ros):
    _, node = ros
    with pytest.raises(ValueError):
        JointStateIntake(node, "x", QOS)
    with pytest.raises(ValueError):
        JointStateIntake(node, "x", QOS, on_message=print, on_block=print)
    with pytest.raises(ValueError):
        create_executor("multi")
