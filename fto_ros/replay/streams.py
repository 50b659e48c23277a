"""The replay's inputs: which topic of the bag plays which role (from the settings, as the
node subscribes), what the bag lacks, and the messages, read and decoded.

The fast path reads metadata.yaml and the MCAP files directly (bag/mcap_scan.py: the
indexes, numpy; no message objects for fixed-layout topics); a bag it does not take goes
through rosbags' BagReader.  Every message the bag lists is read, or a BagError names the
topic: never a silent drop.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..bag import BagError, BagReader
from ..bag.mcap_scan import NotFast, fast_info, read_raw
from ..bag.reader import deserialize, shared_typestore
from ..core.cdr import F64_ARRAY, JOINT_STATE, JointStateDecoder, decode_float_block
from ..core.errors import DecodeError
from ..runner.sources.base import from_message
from .topics import ReplayError, resolve_topic

CLOCK_TOPIC, CLOCK = "/clock", "rosgraph_msgs/msg/Clock"
#: the message type of each role's topic but the source's (which names its own)
ROLE_TYPES = {"truth": F64_ARRAY, "truth_ui": F64_ARRAY, "clock": CLOCK,
              "truth_joints": JOINT_STATE}
_EMPTY = (np.zeros(0, np.int64), [])


@dataclass
class _Streams:
    """The messages of one replay by role: ``(log times ns, values)``.  The source's topics
    (roles named by their keys: measured_output, input, joint_states) and ``clock`` keep
    their raw payloads (the source decodes them); a Float64MultiArray truth is an (N, n)
    float array when every message has n values (else a list of lists), a JointState truth
    a list of messages (core.cdr.JointStateArrays)."""

    truth: tuple = _EMPTY
    truth_ui: tuple = _EMPTY                          # true unknown input, when the bag has it
    truth_joints: tuple = _EMPTY                      # per-joint mode: the truth as JointStates
    #: per role, the log times and raw CDR payloads (Payloads or a list of bytes): the
    #: source's topics, and what the output bag copies
    raw: dict = field(default_factory=dict)
    reader: str = ""

    def times(self, role: str) -> np.ndarray:
        return self.raw.get(role, _EMPTY)[0]


@dataclass
class Inputs:
    """What a replay reads: the bag's summary, the topic of each role, why a ground truth
    is missing, and the streams."""

    info: Any
    roles: dict[str, str]
    truth_topic: str
    truth_note: str | None
    truth_ui_topic: str
    truth_ui_note: str | None
    streams: _Streams
    types: dict = field(default_factory=dict)   # role -> message type


def read_inputs(bag_path: Path, runner, fqn: str, source) -> Inputs:
    """The roles of ``runner``'s settings and ``source``'s topics in the bag at
    ``bag_path``, and their messages."""
    reader = None
    try:
        try:
            info, files = fast_info(bag_path)
        except NotFast:                 # e.g. a lone .mcap file: rosbags says what it holds
            reader = BagReader(bag_path)
            info, files = reader.info(), None
        inp = _roles(info, runner, fqn, bag_path, source)
        topics = sorted(set(inp.roles.values()))
        try:
            raw = read_raw(bag_path, topics, files)
            _check_counts(bag_path, info.topics, {t: len(raw[t][1]) for t in topics})
            inp.streams = _fast_streams(bag_path, raw, inp)
        except (NotFast, BagError) as why:   # the fast path read fewer: rosbags must do better
            reader = reader or BagReader(bag_path)
            inp.streams = _rosbags_streams(bag_path, reader, inp, str(why))
        return inp
    finally:
        if reader is not None:
            reader.close()


#: the role of the ground truth, by its message type (the source's ``truth_msgtype``)
TRUTH_ROLE = {F64_ARRAY: "truth", JOINT_STATE: "truth_joints"}


def _roles(info, runner, fqn: str, bag_path: Path, source) -> Inputs:
    """Which topic plays which role (the node's subscriptions), checked against the bag."""
    settings, obs = runner.settings, runner.observer
    topics = info.topics
    roles: dict[str, str] = {}
    types = dict(ROLE_TYPES)
    for t in source.topics:
        roles[t.key] = resolve_topic(settings[t.setting], fqn)
        types[t.key] = t.msgtype
        what = t.key if t.samples else f"{t.key} (the observer has {obs.n_inputs} known input(s))"
        _check_topic(topics, roles[t.key], t.msgtype, what, bag_path)
    truth_topic = resolve_topic(settings["topics.true_state"], fqn)
    truth_note = None
    if truth_topic not in topics:
        truth_note = f"no ground truth: the bag has no topic {truth_topic}"
    elif topics[truth_topic].msgtype != source.truth_msgtype:
        truth_note = (f"no ground truth: {truth_topic} is {topics[truth_topic].msgtype}; the "
                      f"truth of source {source.name} is a {source.truth_msgtype}")
    else:
        roles[TRUTH_ROLE[source.truth_msgtype]] = truth_topic
    ui_topic = resolve_topic(settings.get("topics.true_unknown_input", "true_unknown_input"), fqn)
    ui_note = None
    if ui_topic in topics and topics[ui_topic].msgtype == F64_ARRAY:
        roles["truth_ui"] = ui_topic
    else:
        ui_note = f"no unknown-input ground truth: the bag has no {F64_ARRAY} topic {ui_topic}"
    if CLOCK_TOPIC in topics and topics[CLOCK_TOPIC].msgtype == CLOCK:
        roles["clock"] = CLOCK_TOPIC                # copied, so the output bag plays alone
    return Inputs(info, roles, truth_topic, truth_note, ui_topic, ui_note, _Streams(), types)


def _decode_truth(s: _Streams, role: str, t, payloads, where: str, typestore) -> None:
    """The ground truth of ``role`` decoded into ``s`` (numpy; rosbags for the rest)."""
    if role == "truth_joints":
        msgs = []
        try:
            for _, _, js in JointStateDecoder().decode_block(payloads):
                msgs += [js._replace(position=p, velocity=v, effort=e)
                         for p, v, e in zip(js.position, js.velocity, js.effort)]
        except DecodeError:
            msgs = [from_message(deserialize(typestore(), p, JOINT_STATE, where, k))
                    for k, p in enumerate(payloads)]
        s.truth_joints = (t, msgs)
        return
    block = decode_float_block(payloads) if len(payloads) else np.zeros((0, 0))
    if block is None:
        block = [np.asarray(deserialize(typestore(), p, F64_ARRAY, where, k).data,
                            dtype=float).tolist() for k, p in enumerate(payloads)]
    setattr(s, role, (t, block))


def _fast_streams(bag_path: Path, raw: dict, inp) -> _Streams:
    s = _Streams(reader="MCAP fast path")
    for role, topic in inp.roles.items():
        t, payloads = raw[topic]
        s.raw[role] = (t, payloads)
        if role in ("truth", "truth_ui", "truth_joints"):
            _decode_truth(s, role, t, payloads, f"{bag_path}: topic {topic}", shared_typestore)
    return s


def _rosbags_streams(bag_path: Path, reader: BagReader, inp: Inputs, why: str) -> _Streams:
    """The streams through rosbags (the messages serialised again: the source decodes, the
    output bag copies)."""
    roles = inp.roles
    topics = sorted(set(roles.values()))
    lists: dict[str, tuple[list, list]] = {topic: ([], []) for topic in topics}
    for topic, t_ns, msg in reader.messages(topics):
        lists[topic][0].append(t_ns)
        lists[topic][1].append(msg)
    _check_counts(bag_path, inp.info.topics, {t: len(lists[t][0]) for t in topics})
    raw = {}
    serialize = reader.typestore.serialize_cdr
    for role, topic in roles.items():
        raw[topic] = (_log_times(lists[topic][0], bag_path, topic),
                      [bytes(serialize(m, inp.types[role])) for m in lists[topic][1]])
    s = _fast_streams(bag_path, raw, inp)
    s.reader = f"rosbags BagReader ({why})"
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
