"""fto-identify's input: an arm's JointState stream read from a bag (positions, efforts and
header stamps of the estimator's joints, the passive joints' positions), the stretch chosen.

A message is used when it names every joint of ``joints`` with a finite position and effort
and its stamp is later than the last one used; the others are counted by reason. A passive
joint missing from a message keeps its last position (at first its default).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..bag import BagError, BagReader
from ..core.errors import ConfigError, FtoRosError

JOINT_STATE = "sensor_msgs/msg/JointState"


class StreamError(FtoRosError, ValueError):
    """A stream the identification cannot use (exit 1): no efforts, joints missing, nothing
    left in the stretch."""


@dataclass
class Stream:
    topic: str
    t: np.ndarray               # s from the first message used
    q: np.ndarray               # samples x joints
    effort: np.ndarray          # samples x joints
    passive: np.ndarray         # samples x passive joints
    skipped: dict = field(default_factory=dict)


def choose_topic(topics: dict, asked: str | None, param: str) -> str:
    """The stream's topic: ``asked`` (--topic) exactly, else the JointState topic that is
    ``param`` (topics.joint_states) or ends with it, else the only one named .../joint_states."""
    states = sorted(name for name, info in topics.items() if info.msgtype == JOINT_STATE)
    if asked:
        if asked not in topics:
            raise ConfigError("--topic", f"the bag has no topic {asked} (its JointState topics: "
                                         f"{', '.join(states) or 'none'})")
        if topics[asked].msgtype != JOINT_STATE:
            raise ConfigError("--topic", f"{asked} carries {topics[asked].msgtype}, not "
                                         f"sensor_msgs/JointState")
        return asked
    tail = "/" + param.strip("/")
    found = [s for s in states if s == tail or s.endswith(tail)]
    if len(found) == 1:
        return found[0]
    if not states:
        raise StreamError("the bag has no sensor_msgs/JointState topic")
    raise ConfigError("--topic", f"choose the stream: the bag's JointState topics are "
                                 f"{', '.join(states)}")


def read_stream(path, topic: str | None, param_topic: str, joints, passive_joints,
                passive_default) -> Stream:
    """The usable messages of the stream (module doc); BagError for an unreadable bag,
    StreamError when nothing is usable."""
    joints, passive_joints = list(joints), list(passive_joints)
    stamps, Q, E, P = [], [], [], []
    skipped = {"missing_joint": 0, "no_effort": 0, "non_finite": 0, "stamp": 0}
    seen_names: set = set()
    last_passive = np.asarray(passive_default, dtype=float).copy()
    with BagReader(path) as bag:
        topic = choose_topic(bag.topics, topic, param_topic)
        last = None
        for _, _, msg in bag.messages([topic]):
            names = list(msg.name)
            seen_names.update(names)
            index = {name: i for i, name in enumerate(names)}
            if not all(j in index for j in joints):
                skipped["missing_joint"] += 1
                continue
            pos, eff = np.asarray(msg.position, float), np.asarray(msg.effort, float)
            cols = [index[j] for j in joints]
            if eff.size < len(names) or pos.size < len(names):
                skipped["no_effort" if eff.size < len(names) else "missing_joint"] += 1
                continue
            q, e = pos[cols], eff[cols]
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(e))):
                skipped["non_finite"] += 1
                continue
            stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
            if last is not None and stamp <= last:
                skipped["stamp"] += 1
                continue
            for k, name in enumerate(passive_joints):
                if name in index and np.isfinite(pos[index[name]]):
                    last_passive[k] = pos[index[name]]
            last = stamp
            stamps.append(stamp)
            Q.append(q)
            E.append(e)
            P.append(last_passive.copy())
    if not stamps:
        missing = [j for j in joints if j not in seen_names]
        if missing and seen_names:
            raise StreamError(f"{topic}: the stream has no joint(s) {', '.join(missing)} (its "
                              f"joints: {', '.join(sorted(seen_names))})")
        if skipped["no_effort"]:
            raise StreamError(f"{topic}: the stream carries no efforts (JointState.effort is "
                              f"empty): nothing to identify from")
        raise StreamError(f"{topic}: no usable message ({_counts(skipped) or 'the topic is empty'})")
    t0 = stamps[0]
    return Stream(topic=topic, t=(np.array(stamps, dtype=np.int64) - t0) * 1e-9,
                  q=np.array(Q), effort=np.array(E),
                  passive=np.array(P).reshape(len(stamps), len(passive_joints)),
                  skipped={k: v for k, v in skipped.items() if v})


def _counts(skipped: dict) -> str:
    return ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in skipped.items() if v)


def stretch_mask(t: np.ndarray, start, end, segments) -> np.ndarray:
    """Samples inside [start, end] (s from the first message) and inside one of
    ``segments`` [(a, b), ...] when given."""
    keep = np.ones(t.size, dtype=bool)
    if start is not None:
        keep &= t >= start
    if end is not None:
        keep &= t <= end
    if segments:
        inside = np.zeros(t.size, dtype=bool)
        for a, b in segments:
            inside |= (t >= a) & (t <= b)
        keep &= inside
    return keep


__all__ = ["BagError", "Stream", "StreamError", "choose_topic", "read_stream", "stretch_mask"]
