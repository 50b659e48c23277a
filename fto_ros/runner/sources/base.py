"""The source protocol: where a runner's samples come from, as one object chosen once.

A source names the topics it takes (:class:`TopicIn`: a key, the setting that names the
topic, the message type, the rank at equal times) and turns a BATCH of one topic's raw CDR
payloads (one message in the node, a block of a bag in the replay) into the runner's event
rows (:class:`Rows`: kind, time, values and intake codes per row; per message its rows,
its sample row, its stamp), with no Python per message where the payloads share a layout.
Its :class:`~fto_ros.runner.sources.plan.OutputPlan` says what is published per sample.
The node and the replay hand the rows to the runner and the runner's outputs to the plan;
neither looks at the mode again (docs/sources.md).

What the numpy codec (core/cdr.py) does not take goes to the caller's ``fallback(payload,
msgtype, key)``, a reference deserialiser (rclpy's in the node, rosbags' in the replay)
that returns a message object or raises: DecodeError refuses that message (counted as
``undecodable_<key>``), anything else (the replay's BagError) propagates.  ROS-free.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ...core.cdr import JointStateArrays
from ...core.errors import DecodeError, UsageError
from ...core.reasons import CODE
from .. import loop as L

#: what a fallback is: (payload bytes, message type, topic key) -> a message object, or raises
Fallback = Callable[[bytes, str, str], object]
#: a message refused before it became rows, with a reason the runner counts by name
PYTHON = 99


@dataclass(frozen=True)
class TopicIn:
    """One subscribed topic of a source."""

    key: str          # "measured_output", "input", "joint_states": the node's counters
    setting: str      # the setting that names the topic
    msgtype: str      # its message type (core.cdr names)
    rank: int         # at equal times lower ranks first (an input applies from its time on)
    samples: bool     # its messages are samples (a measurement each); else inputs only


@dataclass
class Rows:
    """The runner's rows of M messages of one topic (R rows in all)."""

    kind: np.ndarray          # (R,) int8: loop.MEASUREMENT, INPUT, PAIRED, REFUSED or PYTHON
    t: np.ndarray             # (R,) s
    values: np.ndarray        # (R, J, width)
    pre: np.ndarray           # (R, J) int16: the intake's code (0: none, -1: not this joint's)
    first: np.ndarray         # (M + 1,): the rows of message m are first[m]:first[m + 1]
    srow: np.ndarray          # (M,): the row whose status is the sample's (-1: not a sample)
    irow: np.ndarray          # (M,): the input row a sample is paired with (-1: none)
    stamp_ns: np.ndarray      # (M,) int64: the sample's time (receipt / log time, or stamp)
    owner_ns: np.ndarray      # (M,) int64: the time that tells the topic's publishers apart
    whole: np.ndarray         # (M,) bool: refused as a whole (stamp, clock): no sample time
    py_reasons: dict          # row -> reason of each PYTHON row (counted by name)


def one_row_each(M: int, J: int, width: int) -> Rows:
    """Rows of M messages of one row each (filled by the caller)."""
    first = np.arange(M + 1, dtype=np.int64)
    return Rows(np.zeros(M, np.int8), np.zeros(M), np.zeros((M, J, width)),
                np.zeros((M, J), np.int16), first, first[:-1].copy(),
                np.full(M, -1, np.int64), np.zeros(M, np.int64), np.zeros(M, np.int64),
                np.zeros(M, bool), {})


def paired_rows(count: np.ndarray, J: int, width: int) -> Rows:
    """Rows of messages of count[m] rows each (1: a measurement, 2: its input, then it)."""
    M = count.size
    first = np.zeros(M + 1, np.int64)
    np.cumsum(count, out=first[1:])
    R = int(first[-1])
    return Rows(np.zeros(R, np.int8), np.zeros(R), np.zeros((R, J, width)),
                np.zeros((R, J), np.int16), first, first[1:] - 1,
                np.where(count == 2, first[:-1], -1), np.zeros(M, np.int64),
                np.zeros(M, np.int64), np.zeros(M, bool), {})


def from_message(msg) -> JointStateArrays:
    """A JointState message object (a fallback's: rclpy or rosbags) as the codec's arrays."""
    def arr(values) -> np.ndarray:
        a = np.array(values, dtype=np.float64)
        a.flags.writeable = False
        return a
    st = msg.header.stamp
    return JointStateArrays(int(st.sec), int(st.nanosec), str(msg.header.frame_id),
                            tuple(msg.name), arr(msg.position), arr(msg.velocity),
                            arr(msg.effort))


class Source:
    """The protocol (see the module doc); one subclass per input mode.

    ``name``: the mode ('topics', 'joint_states', 'joints'); ``topics``: the TopicIn
    taken, in the order the node opens them (inputs first); ``plan``: the OutputPlan;
    ``executor``: the node's executor for this source under ``node.executor: auto``;
    ``truth_msgtype``: the message type of the ground truth a replay compares with."""

    name = ""
    topics: tuple[TopicIn, ...] = ()
    executor = "single"
    truth_msgtype = ""

    def __init__(self, runner, fallback: Fallback | None = None):
        self.runner = runner
        self.fallback = fallback
        self.undecodable = 0          # messages no decoder took (refused)
        self.by_fallback = 0          # messages the fallback decoded (the codec did not)
        self._topic = {t.key: t for t in self.topics}

    @property
    def width(self) -> int:
        obs = self.runner.observer
        return max(obs.n_outputs, obs.n_inputs, 1)

    def topic(self, key: str) -> TopicIn:
        return self._topic[key]

    def rows(self, key: str, payloads: Sequence, recv_ns: np.ndarray, sent_ns: np.ndarray,
             clock: np.ndarray | None) -> Rows:
        """The rows of the M ``payloads`` of topic ``key``: ``recv_ns`` (M,) when each was
        received (the node's clock at receipt, -1 if it has none yet; the replay: the log
        time), ``sent_ns`` (M,) the sender's time (DDS source timestamp; the log time),
        ``clock`` (M,) s the time a header stamp is checked against (None: not checked)."""
        raise UsageError(f"{type(self).__name__} does not define rows")

    # -- decoding with the fallback ----------------------------------------------------
    def _fallback(self, payload, msgtype: str, key: str):
        """The fallback's message, or a refusal reason (DecodeError from it)."""
        if self.fallback is None:
            return "no decoder"
        try:
            msg = self.fallback(bytes(payload), msgtype, key)
        except DecodeError as exc:
            return str(exc)
        self.by_fallback += 1
        return msg

    def _refuse_undecodable(self, rows: Rows, m: int, key: str, why: str) -> None:
        """Message m (one row) refused as undecodable: a PYTHON row with the reason."""
        self.undecodable += 1
        r = int(rows.first[m])
        rows.kind[r] = PYTHON
        rows.whole[m] = True
        rows.srow[m] = r if self._topic[key].samples else -1
        rows.py_reasons[r] = f"undecodable_{key}"
        self.last_undecodable = why


def stamp_codes(sec: np.ndarray, nsec: np.ndarray, t: np.ndarray, settings,
                clock: np.ndarray | None) -> np.ndarray:
    """Per message, the code of a header stamp refused against ``clock`` (0: none): a zero
    stamp while the clock reads more than ``time.max_gap`` (``zero_stamp``), a stamp more
    than ``time.future_tolerance`` ahead (``future_stamp``); runner/messages.py's rule."""
    codes = np.zeros(t.size, np.int16)
    if clock is None:
        return codes
    codes[t - clock > settings["time.future_tolerance"]] = CODE["future_stamp"]
    codes[(sec == 0) & (nsec == 0) & (clock > settings["time.max_gap"])] = CODE["zero_stamp"]
    return codes


MEASUREMENT, INPUT, PAIRED, REFUSED = L.MEASUREMENT, L.INPUT, L.PAIRED, L.REFUSED
