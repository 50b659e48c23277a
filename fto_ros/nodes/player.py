"""``fto-play BAG``: publish a rosbag2 bag on live topics with its timing (like ``ros2 bag play``).

    fto-play BAG [--rate R] [--clock] [--loop] [--topics T ...] [--delay S]
                 [--wait-for-subscribers [TIMEOUT]] [--ros-args ...]

Reads the bag with :mod:`fto_ros.bag` (rosbags, no ROS install needed) and
republishes ``std_msgs/Float64MultiArray``, ``sensor_msgs/JointState`` and
``rosgraph_msgs/Clock`` messages at their log times (scaled by ``--rate``); other
types are skipped with a note.  With ``--clock`` it publishes ``/clock`` from the
log times, before every message whose log time differs from the previous one (not
at a fixed 40 Hz like ``ros2 bag play --clock``): a node with ``use_sim_time`` that
stamps Float64MultiArray on receipt then gets each sample's own time.  A recorded
``/clock`` topic is not replayed when ``--clock`` is given.

Publishers are reliable, keep last 100, volatile (compatible with best-effort sensor
subscriptions).  ``--wait-for-subscribers`` holds playback until every played topic has
a subscriber (at most TIMEOUT s), so the first samples are not lost to discovery.

``--loop`` replays the bag again and again: the log times (and /clock) jump back at
every restart, which the observer node detects and counts as one 'time_jump' restart.

Exit status (the fto_ros contract): 0 when the bag has been played (or on Ctrl-C),
2 for bad arguments (a usage error, a topic the bag does not have or cannot play),
1 for a missing or unreadable bag.
"""
from __future__ import annotations

import argparse
import array
import math
import sys
import time
from typing import Any, Callable

import numpy as np

FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
JOINT_STATE = "sensor_msgs/msg/JointState"
CLOCK = "rosgraph_msgs/msg/Clock"
SUPPORTED = (FLOAT64_MULTI_ARRAY, JOINT_STATE, CLOCK)
CLOCK_TOPIC = "/clock"


# ------------------------------------------------- rosbags message -> rclpy message
def _doubles(values) -> array.array:
    return array.array("d", np.asarray(values, dtype=np.float64).tobytes())


def _time(stamp):
    from builtin_interfaces.msg import Time
    return Time(sec=int(stamp.sec), nanosec=int(stamp.nanosec))


def to_float64_multi_array(msg):
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    out = Float64MultiArray()
    out.layout.dim = [MultiArrayDimension(label=str(d.label), size=int(d.size), stride=int(d.stride))
                      for d in msg.layout.dim]
    out.layout.data_offset = int(msg.layout.data_offset)
    out.data = _doubles(msg.data)
    return out


def to_joint_state(msg):
    from sensor_msgs.msg import JointState
    out = JointState()
    out.header.stamp = _time(msg.header.stamp)
    out.header.frame_id = str(msg.header.frame_id)
    out.name = [str(n) for n in msg.name]
    out.position = _doubles(msg.position)
    out.velocity = _doubles(msg.velocity)
    out.effort = _doubles(msg.effort)
    return out


def to_clock(msg):
    from rosgraph_msgs.msg import Clock
    return Clock(clock=_time(msg.clock))


CONVERTERS: dict[str, Callable[[Any], Any]] = {
    FLOAT64_MULTI_ARRAY: to_float64_multi_array,
    JOINT_STATE: to_joint_state,
    CLOCK: to_clock,
}


def _ros_type(type_name: str):
    if type_name == FLOAT64_MULTI_ARRAY:
        from std_msgs.msg import Float64MultiArray
        return Float64MultiArray
    if type_name == JOINT_STATE:
        from sensor_msgs.msg import JointState
        return JointState
    from rosgraph_msgs.msg import Clock
    return Clock


def clock_msg(t_ns: int):
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock
    return Clock(clock=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000))


# ----------------------------------------------------------------------------- main
def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="fto-play",
        description="Publish a rosbag2 bag's Float64MultiArray, JointState and Clock messages "
                    "on live topics with their timing (like `ros2 bag play`).",
        epilog="ROS arguments (remappings, -p) go after --ros-args.  Example: "
               "fto-play bags/dc_motor_nominal --clock  (and the node with -p use_sim_time:=true)")
    ap.add_argument("bag", help="rosbag2 directory (or .mcap file)")
    ap.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    ap.add_argument("--clock", action="store_true",
                    help="publish /clock from the log times (for nodes with use_sim_time)")
    ap.add_argument("--loop", action="store_true", help="play the bag again and again")
    ap.add_argument("--topics", nargs="+", metavar="T", help="only these topics (default: all "
                    "topics of a supported type)")
    ap.add_argument("--delay", type=float, default=0.5,
                    help="seconds to wait after start-up so subscribers are discovered (default 0.5)")
    ap.add_argument("--wait-for-subscribers", type=float, nargs="?", const=10.0, default=None,
                    metavar="TIMEOUT",
                    help="before playing, wait (at most TIMEOUT s, default 10) until every played "
                         "topic has a subscriber, then --delay")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    return ap


def _select_topics(topics: dict, wanted: list[str] | None, clock: bool) -> tuple[dict, list[str]]:
    """(topic -> type to play, notes).  BagError-like ValueError for unknown/unsupported topics."""
    notes = []
    if wanted:
        missing = [t for t in wanted if t not in topics]
        if missing:
            raise ValueError(f"no topic(s) {missing} in the bag; it has {sorted(topics)}")
        bad = [f"{t} ({topics[t].msgtype})" for t in wanted if topics[t].msgtype not in SUPPORTED]
        if bad:
            raise ValueError(f"cannot play {', '.join(bad)}: only Float64MultiArray, JointState "
                             "and Clock are supported")
        chosen = {t: topics[t].msgtype for t in wanted}
    else:
        chosen = {t: info.msgtype for t, info in topics.items() if info.msgtype in SUPPORTED}
        skipped = [f"{t} ({info.msgtype})" for t, info in topics.items() if info.msgtype not in SUPPORTED]
        if skipped:
            notes.append("skipping unsupported topic(s): " + ", ".join(skipped))
    if clock and CLOCK_TOPIC in chosen:
        del chosen[CLOCK_TOPIC]
        notes.append("--clock: the recorded /clock is replaced by /clock from the log times")
    return chosen, notes


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``fto-play``; ``argv`` without the program name.  Returns the exit status."""
    import rclpy
    import rclpy.utilities
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from ..bag.reader import BagError, BagReader

    args_all = ["fto-play"] + list(sys.argv[1:] if argv is None else argv)
    try:
        user_args = rclpy.utilities.remove_ros_args(args_all)[1:]
    except Exception as exc:
        print(f"fto-play: error: bad ROS arguments: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    ap = _parser()
    try:
        args = ap.parse_args(user_args)
    except SystemExit as exc:  # --help (0) or a usage error (2, the fto_ros contract)
        return 0 if exc.code == 0 else 2
    if not (args.rate > 0 and math.isfinite(args.rate)):
        print(f"fto-play: error: --rate must be a finite number > 0, got {args.rate}", file=sys.stderr)
        return 2

    try:
        bag = BagReader(args.bag)
    except BagError as exc:
        print(f"fto-play: error: {exc}", file=sys.stderr)
        return 1
    try:
        chosen, notes = _select_topics(bag.topics, args.topics, args.clock)
    except ValueError as exc:       # --topics names a topic the bag does not have
        bag.close()
        print(f"fto-play: error: {args.bag}: {exc}", file=sys.stderr)
        return 2
    if not chosen:
        bag.close()
        print(f"fto-play: error: {args.bag}: nothing to play (no Float64MultiArray, JointState "
              "or Clock topic)", file=sys.stderr)
        return 1

    rclpy.init(args=args_all)
    node = rclpy.create_node("fto_play")
    log = node.get_logger()
    for note in notes:
        log.info(note)
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    pubs = {t: node.create_publisher(_ros_type(ty), t, qos) for t, ty in chosen.items()}
    convert = {t: CONVERTERS[ty] for t, ty in chosen.items()}
    clock_pub = node.create_publisher(_ros_type(CLOCK), CLOCK_TOPIC, qos) if args.clock else None

    played = 0
    code = 0
    try:
        if clock_pub is not None:
            clock_pub.publish(clock_msg(bag.start_ns))
        if args.wait_for_subscribers is not None:
            deadline = time.monotonic() + args.wait_for_subscribers
            while any(p.get_subscription_count() == 0 for p in pubs.values()):
                if time.monotonic() > deadline:
                    log.warning("no subscriber yet on "
                                + ", ".join(t for t, p in pubs.items() if p.get_subscription_count() == 0)
                                + "; playing anyway")
                    break
                time.sleep(0.02)
        time.sleep(max(0.0, args.delay))
        loops = 0
        while True:
            t_first = None
            wall0 = 0.0
            last_clock = None
            for topic, t_ns, msg in bag.messages(list(chosen)):
                if t_first is None:
                    t_first, wall0 = t_ns, time.monotonic()
                delay = wall0 + (t_ns - t_first) * 1e-9 / args.rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if clock_pub is not None and t_ns != last_clock:
                    clock_pub.publish(clock_msg(t_ns))
                    last_clock = t_ns
                pubs[topic].publish(convert[topic](msg))
                played += 1
            loops += 1
            if not args.quiet:
                log.info(f"played {args.bag} ({played} messages so far, loop {loops})")
            if not args.loop or t_first is None:
                break
    except BagError as exc:
        print(f"fto-play: error: {exc}", file=sys.stderr)
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        bag.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
