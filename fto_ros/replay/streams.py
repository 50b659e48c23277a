"""A bag's messages by role (measured output, input, joint states, ground truth), read and
decoded for the replay: the fast MCAP scanner when it can (bag/mcap_scan.py), rosbags
otherwise; every message the bag lists is read, or a BagError names the topic.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..bag import BagError, BagReader
from ..bag.cdr import JOINT_STATE, decode_float_arrays, deserialize
from ..bag.mcap_scan import NotFast, read_raw
from .topics import ReplayError

_EMPTY = (np.zeros(0, np.int64), [])


@dataclass
class _Streams:
    """The messages of one replay by role: ``(log times ns, values or messages)``."""

    inputs: tuple = _EMPTY
    meas: tuple = _EMPTY
    joints: tuple = _EMPTY
    truth: tuple = _EMPTY
    truth_ui: tuple = _EMPTY                          # true unknown input, when the bag has it
    clock: tuple = _EMPTY                             # /clock, copied to the output bag
    #: per role, what the output bag copies: raw CDR payloads (raw) or rosbags messages
    copies: dict = field(default_factory=dict)
    raw: bool = True
    reader: str = ""


def _read_streams(bag_path: Path, reader: BagReader, roles: dict[str, str],
                  typestore, listed: dict) -> _Streams:
    """Read and decode the topics of ``roles`` (role -> topic).  Every message the bag
    lists is read or BagError says which topic lost some: never a silent drop."""
    topics = sorted(set(roles.values()))
    s = _Streams()
    try:
        raw = read_raw(bag_path, topics)
        s.reader = "MCAP fast path"
        _check_counts(bag_path, listed, {t: len(raw[t][1]) for t in topics})
    except NotFast as why:
        raw = None
        s.reader = f"rosbags BagReader ({why})"
    except BagError as err:     # the fast path read fewer: let rosbags try, it must do better
        raw = None
        s.reader = f"rosbags BagReader ({err})"
    if raw is not None:
        for role, topic in roles.items():
            t, payloads = raw[topic]
            where = f"{bag_path}: topic {topic}"
            s.copies[role] = payloads
            if role == "joints":
                s.joints = (t, [deserialize(typestore, p, JOINT_STATE, where, k)
                                for k, p in enumerate(payloads)])
            elif role == "clock":
                s.clock = (t, payloads)
            else:
                setattr(s, role, (t, decode_float_arrays(payloads, typestore, where)))
        return s
    lists: dict[str, tuple[list, list]] = {topic: ([], []) for topic in topics}
    for topic, t_ns, msg in reader.messages(topics):
        lists[topic][0].append(t_ns)
        lists[topic][1].append(msg)
    _check_counts(bag_path, listed, {t: len(lists[t][0]) for t in topics})
    s.raw = False
    for role, topic in roles.items():
        t = _log_times(lists[topic][0], bag_path, topic)
        msgs = lists[topic][1]
        s.copies[role] = msgs
        if role in ("joints", "clock"):
            setattr(s, role, (t, msgs))
        else:
            setattr(s, role, (t, [np.asarray(m.data, dtype=float).tolist() for m in msgs]))
    return s


def _log_times(times: list, bag_path: Path, topic: str) -> np.ndarray:
    """Log times (ns) as int64, or BagError for one no ROS time can be (>= 2^63 ns)."""
    try:
        return np.asarray(times, dtype=np.int64)
    except OverflowError:
        raise BagError(f"{bag_path}: topic {topic}: a log time beyond 2^63 ns (a corrupt "
                       "file?)") from None


def _check_counts(bag_path: Path, listed: dict, got: dict[str, int]) -> None:
    """BagError unless every topic gave as many messages as the bag lists for it."""
    for topic, n in got.items():
        want = listed[topic].count
        if n != want:
            raise BagError(f"{bag_path}: topic {topic}: read {n} of the {want} messages the bag "
                           "lists (a truncated or corrupt file?)")


def _check_topic(topics: dict, topic: str, msgtype: str, what: str, bag_path: Path) -> None:
    if topic not in topics:
        listing = ", ".join(f"{k} ({v.msgtype})" for k, v in topics.items()) or "none"
        raise ReplayError(f"{bag_path}: the bag has no {what} topic {topic} (from the params "
                          f"file); the bag's topics: {listing}")
    if topics[topic].msgtype != msgtype:
        raise ReplayError(f"{bag_path}: topic {topic} has type {topics[topic].msgtype}; "
                          f"the {what} topic must be {msgtype}")
