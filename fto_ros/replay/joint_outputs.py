"""The replay's output bag in the per-joint mode (``joints``): one JointState per sample on
``~/estimated_joint_states``, every joint by name (runner/joints.py's OutputPlan: position,
velocity, effort = the unknown-input estimate where the observer has one), stamped with the
measurement's stamp, as the node publishes it; a joint without an output in a message
(rejected, held) is left out of that message.  /diagnostics: the node's status, then one
per joint.
"""
from __future__ import annotations

import numpy as np

from ..bag.cdr import JOINT_STATE
from ..runner.joints import OutputPlan
from .blocks import OutputBlock
from .outputs import OutputBag


class JointsOutputBag(OutputBag):
    """OutputBag of a runner with ``joints``."""

    def _estimates(self, fqn: str) -> None:
        self.plan = OutputPlan(self.runner)
        self.js = f"{fqn}/estimated_joint_states"
        self.bag.connect(self.js, JOINT_STATE)
        self.counts[self.js] = 0

    def publish(self, b: OutputBlock) -> None:
        k = b.t_ns.size
        if not k:
            return
        t = b.t_ns
        sec, nsec = t // 1_000_000_000, t % 1_000_000_000
        fields = self.plan.fields(b.x, b.w)
        # runs of rows that carry the same joints (all of them, but for a refused or held one)
        cuts = np.flatnonzero(np.any(b.ok[1:] != b.ok[:-1], axis=1)) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, k]):
            mask = b.ok[lo]
            names = [n for n, keep in zip(self.plan.names, mask) if keep]
            parts = [f[lo:hi][:, mask].reshape(hi - lo, -1) for f in fields]
            enc = self.enc.joint_state_block(names, tuple(p.shape[1] for p in parts), self.frame)
            self.bag.write_block(self.js, JOINT_STATE, t[lo:hi], enc(sec[lo:hi], nsec[lo:hi], *parts))
        self.counts[self.js] += k
        self.published += k
