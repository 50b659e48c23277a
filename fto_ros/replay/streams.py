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
from ..bag.cdr import (F64_ARRAY, JOINT_STATE, decode_float_arrays, decode_float_block,
                       decode_joint_states, deserialize)
from ..bag.mcap_scan import NotFast, fast_info, read_raw
from ..bag.reader import shared_typestore
from .topics import ReplayError, resolve_topic

CLOCK_TOPIC, CLOCK = "/clock", "rosgraph_msgs/msg/Clock"
#: the message type of each role's topic
ROLE_TYPES = {"meas": F64_ARRAY, "inputs": F64_ARRAY, "joints": JOINT_STATE, "truth": F64_ARRAY,
              "truth_ui": F64_ARRAY, "clock": CLOCK, "truth_joints": JOINT_STATE}
#: the roles whose messages are JointStates
_JOINT_STATE_ROLES = ("joints", "truth_joints")
_EMPTY = (np.zeros(0, np.int64), [])


@dataclass
class _Streams:
    """The messages of one replay by role: ``(log times ns, values)``; the values of a
    Float64MultiArray role are an (N, n) float array when every message has n values (else
    a list of lists), of ``joints`` JointState messages, of ``clock`` the raw payloads."""

    inputs: tuple = _EMPTY
    meas: tuple = _EMPTY
    joints: tuple = _EMPTY
    truth: tuple = _EMPTY
    truth_ui: tuple = _EMPTY                          # true unknown input, when the bag has it
    truth_joints: tuple = _EMPTY                      # per-joint mode: the truth as JointStates
    clock: tuple = _EMPTY                             # /clock, copied to the output bag
    #: per role, the raw CDR payloads the output bag copies (Payloads or a list of bytes)
    copies: dict = field(default_factory=dict)
    reader: str = ""


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


def read_inputs(bag_path: Path, runner, fqn: str) -> Inputs:
    """The roles of ``runner``'s settings in the bag at ``bag_path``, and their messages."""
    reader = None
    try:
        try:
            info, files = fast_info(bag_path)
        except NotFast:                 # e.g. a lone .mcap file: rosbags says what it holds
            reader = BagReader(bag_path)
            info, files = reader.info(), None
        inp = _roles(info, runner, fqn, bag_path)
        topics = sorted(set(inp.roles.values()))
        try:
            raw = read_raw(bag_path, topics, files)
            _check_counts(bag_path, info.topics, {t: len(raw[t][1]) for t in topics})
            inp.streams = _fast_streams(bag_path, raw, inp.roles)
        except (NotFast, BagError) as why:   # the fast path read fewer: rosbags must do better
            reader = reader or BagReader(bag_path)
            inp.streams = _rosbags_streams(bag_path, reader, inp, str(why))
        return inp
    finally:
        if reader is not None:
            reader.close()


def _roles(info, runner, fqn: str, bag_path: Path) -> Inputs:
    """Which topic plays which role (the node's subscriptions), checked against the bag."""
    settings, obs = runner.settings, runner.observer
    topics = info.topics
    roles: dict[str, str] = {}
    if settings["source"] == "topics":
        roles["meas"] = resolve_topic(settings["topics.measured_output"], fqn)
        _check_topic(topics, roles["meas"], F64_ARRAY, "measured_output", bag_path)
        if obs.n_inputs:
            roles["inputs"] = resolve_topic(settings["topics.input"], fqn)
            _check_topic(topics, roles["inputs"], F64_ARRAY,
                         f"input (the observer has {obs.n_inputs} known input(s))", bag_path)
    else:
        roles["joints"] = resolve_topic(settings["topics.joint_states"], fqn)
        _check_topic(topics, roles["joints"], JOINT_STATE, "joint_states", bag_path)
    truth_topic = resolve_topic(settings["topics.true_state"], fqn)
    truth_note = None
    if truth_topic not in topics:
        truth_note = f"no ground truth: the bag has no topic {truth_topic}"
    elif (runner.joints or runner.intake is not None) and \
            topics[truth_topic].msgtype == JOINT_STATE:
        roles["truth_joints"] = truth_topic          # mapped by joint name
    elif runner.joints:
        truth_note = (f"no ground truth: {truth_topic} is {topics[truth_topic].msgtype}; with "
                      f"joints the truth is a {JOINT_STATE} (by joint name)")
    elif topics[truth_topic].msgtype != F64_ARRAY:
        truth_note = (f"no ground truth: {truth_topic} is {topics[truth_topic].msgtype}, "
                      f"not {F64_ARRAY}")
    else:
        roles["truth"] = truth_topic
    ui_topic = resolve_topic(settings.get("topics.true_unknown_input", "true_unknown_input"), fqn)
    ui_note = None
    if ui_topic in topics and topics[ui_topic].msgtype == F64_ARRAY:
        roles["truth_ui"] = ui_topic
    else:
        ui_note = f"no unknown-input ground truth: the bag has no {F64_ARRAY} topic {ui_topic}"
    if CLOCK_TOPIC in topics and topics[CLOCK_TOPIC].msgtype == CLOCK:
        roles["clock"] = CLOCK_TOPIC                # copied, so the output bag plays alone
    return Inputs(info, roles, truth_topic, truth_note, ui_topic, ui_note, _Streams())


def _fast_streams(bag_path: Path, raw: dict, roles: dict[str, str]) -> _Streams:
    s = _Streams(reader="MCAP fast path")
    typestore = None                    # only for what the numpy decoders leave
    for role, topic in roles.items():
        t, payloads = raw[topic]
        where = f"{bag_path}: topic {topic}"
        s.copies[role] = payloads
        if role == "clock":
            s.clock = (t, payloads)
        elif role in _JOINT_STATE_ROLES:
            msgs = decode_joint_states(payloads)
            if msgs is None:
                typestore = typestore or shared_typestore()
                msgs = [deserialize(typestore, p, JOINT_STATE, where, k)
                        for k, p in enumerate(payloads)]
            setattr(s, role, (t, msgs))
        else:
            block = decode_float_block(payloads)
            if block is None:
                typestore = typestore or shared_typestore()
                block = decode_float_arrays(payloads, typestore, where)
            setattr(s, role, (t, block))
    return s


def _rosbags_streams(bag_path: Path, reader: BagReader, inp: Inputs, why: str) -> _Streams:
    """The streams through rosbags (deserialised messages; the copies serialised again)."""
    roles = inp.roles
    topics = sorted(set(roles.values()))
    lists: dict[str, tuple[list, list]] = {topic: ([], []) for topic in topics}
    for topic, t_ns, msg in reader.messages(topics):
        lists[topic][0].append(t_ns)
        lists[topic][1].append(msg)
    _check_counts(bag_path, inp.info.topics, {t: len(lists[t][0]) for t in topics})
    s = _Streams(reader=f"rosbags BagReader ({why})")
    serialize = reader.typestore.serialize_cdr
    for role, topic in roles.items():
        t = _log_times(lists[topic][0], bag_path, topic)
        msgs = lists[topic][1]
        s.copies[role] = [bytes(serialize(m, ROLE_TYPES[role])) for m in msgs]
        if role == "clock":
            s.clock = (t, s.copies[role])
        elif role in _JOINT_STATE_ROLES:
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
