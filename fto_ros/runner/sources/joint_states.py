"""``source: joint_states`` without ``joints``: one observer of the whole plant, y from the
``joint_states.output_field`` of ``joint_states.output_joints`` and u from the
``input_field`` of ``input_joints`` (an arm family: its intake's joints,
runner/arm_intake.py), by name, stamped with the header stamp (the rule:
runner/messages.py ``joint_state_sample``).  A message with inputs is two rows: its input,
then its measurement PAIRED with it (skipped when that input is refused: never paired with
a bad u).  The JointState decoding (core/cdr.py, the fallback for the rest) is shared with
the per-joint source (joints.py).  ROS-free.
"""
from __future__ import annotations

import numpy as np

from ...core.cdr import F64_ARRAY, JOINT_STATE, JointStateDecoder, stamp_ns
from ...core.errors import DecodeError
from ...core.reasons import CODE
from ..messages import joint_state_sample
from .base import (INPUT, MEASUREMENT, PAIRED, PYTHON, REFUSED, Rows, Source, TopicIn,
                   from_message, paired_rows)
from .plan import whole_plant_plan


class JointStateSource(Source):
    """What both JointState sources share: the topic and the decoding."""

    executor = "single"
    topics = (TopicIn("joint_states", "topics.joint_states", JOINT_STATE, 1, True),)

    def __init__(self, runner, fallback=None):
        super().__init__(runner, fallback)
        self.decoder = JointStateDecoder()

    def _one(self, payload):
        """One payload -> (sec, nsec, arrays of one message as (1, n)) or a refusal reason."""
        try:
            js = self.decoder.decode(payload)
        except DecodeError:
            msg = self._fallback(payload, JOINT_STATE, "joint_states")
            if isinstance(msg, str):
                return msg
            js = from_message(msg)
        return (np.array([js.sec], np.int64), np.array([js.nanosec], np.int64),
                js._replace(position=js.position[None], velocity=js.velocity[None],
                            effort=js.effort[None]))

    def runs(self, payloads) -> list:
        """[(first message, sec (k,), nanosec (k,), arrays (k, n)) or (message, reason)]."""
        if len(payloads) > 1:
            try:
                out, m = [], 0
                for sec, nsec, js in self.decoder.decode_block(payloads):
                    out.append((m, sec, nsec, js))
                    m += sec.size
                return out
            except DecodeError:      # one odd payload: each on its own (fallback, refusal)
                pass
        out = []
        for m, p in enumerate(payloads):
            got = self._one(p)
            out.append((m, got) if isinstance(got, str) else (m, *got))
        return out

    def _allocate(self, runs, M: int, two: bool, J: int) -> Rows:
        """The rows of M messages: 2 each when they carry inputs (``two``), 1 each refused
        as undecodable; those refused are marked."""
        count = np.full(M, 2 if two else 1, np.int64)
        for run in runs:
            if len(run) == 2:
                count[run[0]] = 1
        rows = paired_rows(count, J, self.width)
        for run in runs:
            if len(run) == 2:
                rows.irow[run[0]] = -1
                self._refuse_undecodable(rows, run[0], "joint_states", run[1])
        return rows


class WholeJointStateSource(JointStateSource):
    """One observer of the whole plant from JointStates (see the module doc)."""

    name = "joint_states"
    truth_msgtype = F64_ARRAY

    def __init__(self, runner, fallback=None):
        super().__init__(runner, fallback)
        self.plan = whole_plant_plan(runner)
        if runner.intake is not None:     # an arm's truth: JointStates, by joint name
            self.truth_msgtype = JOINT_STATE

    def rows(self, key, payloads, recv_ns, sent_ns, clock) -> Rows:
        settings, intake = self.runner.settings, self.runner.intake   # an arm's: by name
        M = len(payloads)
        samples: list = [None] * M
        stamps = np.zeros(M, np.int64)
        for run in self.runs(payloads):
            if len(run) == 2:
                samples[run[0]] = run
                continue
            m0, sec, nsec, js = run
            stamps[m0:m0 + sec.size] = stamp_ns(sec, nsec)
            for i in range(sec.size):
                one = js._replace(sec=int(sec[i]), nanosec=int(nsec[i]), position=js.position[i],
                                  velocity=js.velocity[i], effort=js.effort[i])
                samples[m0 + i] = joint_state_sample(
                    one, settings, None if clock is None else float(clock[m0 + i]), intake)
        count = np.array([2 if s.__class__ is tuple and len(s) == 3 and s[2] is not None else 1
                          for s in samples], np.int64)
        rows = paired_rows(count, 1, self.width)
        rows.stamp_ns[:] = rows.owner_ns[:] = stamps
        for m, sample in enumerate(samples):
            self._fill(rows, m, sample)
        return rows

    def _fill(self, rows: Rows, m: int, sample) -> None:
        r = int(rows.first[m])
        if sample.__class__ is tuple and len(sample) == 2:     # undecodable
            self._refuse_undecodable(rows, m, "joint_states", sample[1])
        elif sample.__class__ is str:                        # refused as a whole
            rows.whole[m] = True
            if sample in CODE:
                rows.kind[r], rows.pre[r] = REFUSED, CODE[sample]
            else:
                rows.kind[r] = PYTHON
                rows.py_reasons[r] = sample
        else:
            t, y, u = sample
            rows.t[r:int(rows.first[m + 1])] = t
            if u is not None:
                rows.kind[r] = INPUT
                rows.values[r, 0, :len(u)] = u
                r += 1
            rows.kind[r] = PAIRED if u is not None else MEASUREMENT
            rows.values[r, 0, :len(y)] = y
