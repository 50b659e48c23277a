"""``fto-play BAG``: publish a rosbag2 bag on live topics with its timing (like ``ros2 bag play``).

    fto-play BAG [--rate R] [--clock] [--loop] [--topics T ...] [--delay S]
                 [--wait-for-subscribers [TIMEOUT]] [--junk FRACTION [--seed N]] [--ros-args ...]

Reads the bag with :mod:`fto_ros.bag` (rosbags, no ROS install needed) and
republishes ``std_msgs/Float64MultiArray``, ``sensor_msgs/JointState`` and
``rosgraph_msgs/Clock`` messages at their log times (scaled by ``--rate``); other
types are skipped with a note.  With ``--clock`` it publishes ``/clock`` from the
log times, before every message whose log time differs from the previous one (not
at a fixed 40 Hz like ``ros2 bag play --clock``): a node with ``use_sim_time`` that
stamps Float64MultiArray on receipt then gets each sample's own time.  A recorded
``/clock`` topic is not replayed when ``--clock`` is given.

Publishers are reliable, keep last 100, volatile (compatible with best-effort sensor
subscriptions).  ``--wait-for-subscribers`` holds playback until the topics given with
``--topics`` all have a subscriber, or (without ``--topics``) until any played topic has
one (a bag holds topics nobody listens to, e.g. the ground truth), at most TIMEOUT s,
so the first samples are not lost to discovery.

``--junk F`` tests a node's robustness the way a real stream does: after a fraction F of
the Float64MultiArray and JointState messages it publishes one junk message on the same
topic (seeded by ``--seed``): NaN or 1e300 values, a wrong length, an empty array, and for
JointState a missing joint, a stamp 1 s back, negative or far in the future.  A node
must reject and count every one (its /diagnostics say how).

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

from ..core.errors import BadArgument

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
    ap.add_argument("--junk", type=float, default=0.0, metavar="F",
                    help="after a fraction F of the data messages publish one junk message on "
                         "the same topic (robustness tests; default 0)")
    ap.add_argument("--seed", type=int, default=0, help="seed of --junk (default 0)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    return ap


#: junk families, per message type
JUNK_ARRAY = ("nan", "absurd", "wrong_length", "empty")
JUNK_JOINT_STATE = JUNK_ARRAY + ("missing_joint", "back_1s", "negative_stamp", "future_stamp")


def junk_message(msg, rng) -> tuple[str, Any]:
    """A junk copy of the rclpy message ``msg`` (Float64MultiArray or JointState): (family, msg)."""
    js = hasattr(msg, "header")
    kinds = JUNK_JOINT_STATE if js else JUNK_ARRAY
    kind = kinds[int(rng.integers(len(kinds)))]
    values = list(msg.position if js else msg.data)
    n = max(len(values), 1)
    bad = {"nan": [float("nan")] * n, "absurd": [1e300] * n, "wrong_length": values + [0.0],
           "empty": []}.get(kind, values)
    if not js:
        out = type(msg)()
        out.data = _doubles(bad)
        return kind, out
    out = type(msg)()
    out.header.stamp.sec, out.header.stamp.nanosec = msg.header.stamp.sec, msg.header.stamp.nanosec
    out.name = list(msg.name)
    out.position, out.velocity, out.effort = _doubles(bad), msg.velocity, msg.effort
    if kind == "missing_joint":
        out.name = [n_ + "_missing" for n_ in msg.name]
    elif kind == "back_1s":
        out.header.stamp.sec = max(msg.header.stamp.sec - 1, 0)
    elif kind == "negative_stamp":
        out.header.stamp.sec = -5
    elif kind == "future_stamp":
        out.header.stamp.sec = min(msg.header.stamp.sec + 100000, 2 ** 31 - 1)
    return kind, out


def _select_topics(topics: dict, wanted: list[str] | None, clock: bool) -> tuple[dict, list[str]]:
    """(topic -> type to play, notes).  BagError-like ValueError for unknown/unsupported topics."""
    notes = []
    if wanted:
        missing = [t for t in wanted if t not in topics]
        if missing:
            raise BadArgument(f"no topic(s) {missing} in the bag; it has {sorted(topics)}")
        bad = [f"{t} ({topics[t].msgtype})" for t in wanted if topics[t].msgtype not in SUPPORTED]
        if bad:
            raise BadArgument(f"cannot play {', '.join(bad)}: only Float64MultiArray, JointState "
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
    if not 0.0 <= args.junk <= 1.0:
        print(f"fto-play: error: --junk must be a fraction in [0, 1], got {args.junk}", file=sys.stderr)
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
    junk: dict[str, int] = {}
    junk_rng = np.random.default_rng(args.seed) if args.junk > 0 else None
    try:
        if clock_pub is not None:
            clock_pub.publish(clock_msg(bag.start_ns))
        if args.wait_for_subscribers is not None:
            # the topics asked for all need a subscriber; without --topics any one will do
            waiting = list(pubs) if args.topics else []
            deadline = time.monotonic() + args.wait_for_subscribers
            while (any(pubs[t].get_subscription_count() == 0 for t in waiting) if waiting
                   else all(p.get_subscription_count() == 0 for p in pubs.values())):
                if time.monotonic() > deadline:
                    log.warning("no subscriber yet on " + ", ".join(
                        t for t, p in pubs.items() if p.get_subscription_count() == 0)
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
                out = convert[topic](msg)
                pubs[topic].publish(out)
                played += 1
                if junk_rng is not None and topic != CLOCK_TOPIC and junk_rng.random() < args.junk:
                    kind, bad = junk_message(out, junk_rng)
                    pubs[topic].publish(bad)
                    junk[kind] = junk.get(kind, 0) + 1
            loops += 1
            if not args.quiet:
                log.info(f"played {args.bag} ({played} messages so far, loop {loops})"
                         + (f"; junk sent: {sum(junk.values())} "
                            f"({', '.join(f'{k} {v}' for k, v in sorted(junk.items()))})"
                            if junk else ""))
            if not args.loop or t_first is None:
                break
    except BagError as exc:
        print(f"fto-play: error: {exc}", file=sys.stderr)
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:           # Ctrl-C while waiting: rclpy's context is gone under us
        if rclpy.ok():
            raise
    finally:
        bag.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
