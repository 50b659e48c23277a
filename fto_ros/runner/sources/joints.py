"""``joints: [names]``: one observer per joint, every joint's sample from one JointState by
name (runner/intake.py's rules, a run of messages of one layout at a time): y from
``joint_states.output_fields``, u from the first m of ``joint_states.input_fields``.  A
joint missing from the message or named twice, a field shorter than ``name``, refuses that
joint only, with its reason; a header stamp refused against the clock (``zero_stamp``,
``future_stamp``) refuses every joint.  With inputs a message is two rows: the inputs,
then the measurements PAIRED with them.  Outputs: the per-joint plan (plan.py).  ROS-free.
"""
from __future__ import annotations

import numpy as np

from ...core.cdr import JOINT_STATE, stamp_ns
from ..intake import FIELD_MISSING, JointIntake
from .base import INPUT, PAIRED, MEASUREMENT, Rows, stamp_codes
from .joint_states import JointStateSource
from .plan import per_joint_plan


class JointsSource(JointStateSource):
    """Per-joint samples from JointStates (see the module doc)."""

    name = "joints"
    executor = "events"
    truth_msgtype = JOINT_STATE

    def __init__(self, runner, fallback=None):
        super().__init__(runner, fallback)
        s = runner.settings
        self.plan = per_joint_plan(runner)
        self.intake = JointIntake(runner.joints, s["joint_states.output_fields"],
                                  s["joint_states.input_fields"], runner.observer.n_inputs)

    def rows(self, key, payloads, recv_ns, sent_ns, clock) -> Rows:
        intake = self.intake
        J = len(intake.joints)
        two = bool(intake.in_fields)
        runs = self.runs(payloads)
        rows = self._allocate(runs, len(payloads), two, J)
        settings = self.runner.settings
        for run in runs:
            if len(run) == 2:
                continue
            m0, sec, nsec, js = run
            k = sec.size
            ms = slice(m0, m0 + k)
            rows.stamp_ns[ms] = rows.owner_ns[ms] = stamp_ns(sec, nsec)
            names = js.name
            if names != intake._names:
                intake._lookup(tuple(names))
            refused = np.broadcast_to(intake._refused, (k, J)).copy()
            y, u = self._fields(js, intake.out_fields, refused), None
            if two:
                u = self._fields(js, intake.in_fields, refused)
            t = sec + nsec * 1e-9
            codes = stamp_codes(sec, nsec, t, settings, None if clock is None else clock[ms])
            whole = codes != 0
            refused[whole] = codes[whole, None]
            rows.whole[ms] = whole
            r = rows.first[m0:m0 + k]
            if two:
                rows.kind[r] = INPUT
                rows.t[r] = t
                rows.values[r, :, :u.shape[2]] = u
                rows.pre[r] = np.where(refused != 0, -1, 0)
                r = r + 1
            rows.kind[r] = PAIRED if two else MEASUREMENT
            rows.t[r] = t
            rows.values[r, :, :y.shape[2]] = y
            rows.pre[r] = refused
        return rows

    def _fields(self, js, fields, refused: np.ndarray) -> np.ndarray:
        """(k, J, len(fields)) values of the run's ``fields`` for every joint; a field not
        as long as ``name`` refuses the joints not refused yet (in place)."""
        idx = self.intake._index
        count = len(js.name)
        out = np.zeros((refused.shape[0], refused.shape[1], len(fields)))
        for c, field in enumerate(fields):
            values = getattr(js, field)
            if values.shape[1] != count:
                refused[refused == 0] = FIELD_MISSING[field]
            elif count:
                out[:, :, c] = values[:, idx]
        return out

