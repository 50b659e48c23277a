"""``source: topics``: y on a Float64MultiArray topic (``topics.measured_output``), u on
another (``topics.input``, taken only when the observer has inputs); each message stamped
with its receipt time (the node: its clock when DDS received it; the replay: the log time,
the recording's receipt time).  A message of another length than p (m) is refused
(``measurement_wrong_length``, ``input_wrong_length``); one received before the node's
clock has a time (sim time without /clock yet) as ``waiting_for_clock``.  ROS-free.
"""
from __future__ import annotations

import numpy as np

from ...core.cdr import F64_ARRAY, FloatDecoder, decode_float_block
from ...core.errors import DecodeError
from ...core.reasons import CODE
from .base import INPUT, MEASUREMENT, REFUSED, Rows, Source, TopicIn, one_row_each
from .plan import whole_plant_plan

_WAITING = CODE["waiting_for_clock"]


class TopicsSource(Source):
    """Float64MultiArray y and u (see the module doc)."""

    name = "topics"
    executor = "single"
    truth_msgtype = F64_ARRAY

    def __init__(self, runner, fallback=None):
        obs = runner.observer
        topics = [TopicIn("measured_output", "topics.measured_output", F64_ARRAY, 1, True)]
        if obs.n_inputs:     # input first: u_k stored before y_k at equal times
            topics.insert(0, TopicIn("input", "topics.input", F64_ARRAY, 0, False))
        self.topics = tuple(topics)
        super().__init__(runner, fallback)
        self.plan = whole_plant_plan(runner)
        self._decoders = {t.key: FloatDecoder() for t in self.topics}
        self._spec = {"measured_output": (MEASUREMENT, obs.n_outputs,
                                          CODE["measurement_wrong_length"]),
                      "input": (INPUT, obs.n_inputs, CODE["input_wrong_length"])}

    def _data(self, key: str, payloads) -> list:
        """Each payload's data (a float array), or a refusal reason string."""
        dec = self._decoders[key]
        out = []
        for p in payloads:
            try:
                out.append(dec.decode(p))
            except DecodeError:
                msg = self._fallback(p, F64_ARRAY, key)
                out.append(msg if isinstance(msg, str) else np.asarray(msg.data, dtype=float))
        return out

    def rows(self, key, payloads, recv_ns, sent_ns, clock) -> Rows:
        kind, width, wrong = self._spec[key]
        M = len(payloads)
        rows = one_row_each(M, 1, self.width)
        recv = np.asarray(recv_ns, dtype=np.int64)
        rows.t[:] = recv / 1e9        # the replay's and the golden master's ns -> s (not * 1e-9)
        rows.stamp_ns[:] = recv
        rows.owner_ns[:] = sent_ns
        block = decode_float_block(payloads) if M > 1 else None
        codes = np.zeros(M, np.int16)
        if block is not None:
            if block.shape[1] == width:
                rows.values[:, 0, :width] = block
            else:
                codes[:] = wrong
        else:
            for m, data in enumerate(self._data(key, payloads)):
                if isinstance(data, str):
                    self._refuse_undecodable(rows, m, key, data)
                elif data.size == width:
                    rows.values[m, 0, :width] = data
                else:
                    codes[m] = wrong
        codes[recv < 0] = _WAITING
        rows.whole[:] |= codes != 0
        rows.pre[:, 0] = codes
        python = rows.kind == 99
        rows.kind[:] = np.where(python, 99, np.where(codes != 0, REFUSED, kind))
        if kind == INPUT:
            rows.srow[:] = -1
        return rows
