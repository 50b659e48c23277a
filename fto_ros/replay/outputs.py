"""The replay's output bag: the input topics copied as read, what the node publishes for
each accepted sample, and /diagnostics, written a block at a time.

Every output message has a fixed layout (labelled Float64MultiArray, JointState with fixed
names), so a block of k samples is encoded as one (k, L) byte array (bag/cdr.py) and
written as one block per topic (bag/writer.py): no Python per message.  Log time and
header stamp of an output = its sample time, as the node stamps them; a non-finite
convergence value (guaranteed_time = inf: no guarantee) is published as -1, as the node
does.
"""
from __future__ import annotations

import numpy as np

from ..bag import BagWriter
from ..bag.cdr import F64_ARRAY, JOINT_STATE, Encoders
from ..runner.runner import convergence_fields
from ..runner.status import LEVEL_NAMES
from . import events as E
from .blocks import OutputBlock
from .streams import ROLE_TYPES

#: log times from here on cannot be header stamps (int32 seconds)
MAX_STAMP_NS = 2 ** 31 * 1_000_000_000


class OutputBag:
    """Writes one replay's outputs into ``bag`` (an open BagWriter)."""

    def __init__(self, bag: BagWriter, runner, fqn: str, inp):
        settings, obs = runner.settings, runner.observer
        self.bag, self.runner, self.settings = bag, runner, settings
        self.enc = enc = Encoders(bag.typestore)
        self.streams = streams = inp.streams
        self.counts: dict[str, int] = {}
        self.status_levels: dict[str, int] = {}
        # the input topics, copied (log times as in the input bag): the output bag holds
        # what the estimates were estimated from, and plays on its own
        self.copy_topic = dict(inp.roles)
        for role, topic in self.copy_topic.items():
            bag.connect(topic, ROLE_TYPES[role])
            self.counts[topic] = len(streams.copies[role])
        self._cursor = {role: 0 for role in self.copy_topic}
        self.frame = settings["output.frame_id"]
        self.ui_names: list[str] = []
        self._estimates(fqn)
        bag.connect("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        # as the node: status name "<node name>: observer", hardware_id defaults to the type
        self.diag_name = f"{fqn.rsplit('/', 1)[-1]}: observer"
        self.hw_id = settings["diagnostics.hardware_id"] or runner.observer_type
        self.published = 0

    def _estimates(self, fqn: str) -> None:
        """Connect what the node publishes: labelled arrays, stamped estimates (JointState)."""
        bag, obs, settings, enc, frame = self.bag, self.runner.observer, self.settings, self.enc, self.frame
        names = list(obs.state_names)
        self.est, self.est_st, self.conv = (f"{fqn}/state_estimate",
                                            f"{fqn}/state_estimate_stamped", f"{fqn}/convergence")
        for topic, msgtype in ((self.est, F64_ARRAY), (self.est_st, JOINT_STATE),
                               (self.conv, F64_ARRAY)):
            bag.connect(topic, msgtype)
        self.enc_est = enc.float_block(obs.n_states, names)
        self.enc_est_st = enc.joint_state_block(names, (obs.n_states, 0, 0), frame)
        fields = convergence_fields(obs)
        self.enc_conv = enc.float_block(len(fields), fields)
        self.ui = self.ui_st = None
        if obs.has_unknown_input:
            self.ui_names = list(getattr(obs, "unknown_input_names", None) or
                                 [f"zeta{j}" for j in range(obs.n_outputs)])
            self.ui, self.ui_st = (f"{fqn}/unknown_input_estimate",
                                   f"{fqn}/unknown_input_estimate_stamped")
            bag.connect(self.ui, F64_ARRAY)
            bag.connect(self.ui_st, JOINT_STATE)
            self.enc_ui = enc.float_block(len(self.ui_names), self.ui_names)
            self.enc_ui_st = enc.joint_state_block(self.ui_names, (len(self.ui_names), 0, 0),
                                                   frame)
        self.js = f"{fqn}/estimated_joint_states" \
            if settings["estimated_joint_states.joint_names"] else None
        if self.js:
            bag.connect(self.js, JOINT_STATE)
        self.js_map = self.runner.joint_state_map
        for topic in (self.est, self.est_st, self.conv, self.ui, self.ui_st, self.js):
            if topic:
                self.counts[topic] = 0

    # -- copies -------------------------------------------------------------------------
    def copy(self, ev: E.Events, start: int, stop: int) -> None:
        """Copy the input messages of the events ``[start, stop)`` (each stream's next ones)."""
        per_kind = np.bincount(ev.kind[start:stop], minlength=len(E.ROLE))
        for kind, role in E.ROLE.items():
            n = int(per_kind[kind])
            if not n or role not in self.copy_topic:
                continue
            lo = self._cursor[role]
            t, payloads = getattr(self.streams, role)[0], self.streams.copies[role]
            part = payloads.matrix[lo:lo + n] if getattr(payloads, "matrix", None) is not None \
                else [payloads[k] for k in range(lo, lo + n)]
            self.bag.write_block(self.copy_topic[role], ROLE_TYPES[role], t[lo:lo + n], part)
            self._cursor[role] = lo + n

    # -- estimates ----------------------------------------------------------------------
    def publish(self, b: OutputBlock) -> None:
        """Write what the node publishes for the samples of ``b`` with an output."""
        k = b.t_ns.size
        if not k:
            return
        bag, t = self.bag, b.t_ns
        sec, nsec = t // 1_000_000_000, t % 1_000_000_000
        none = np.zeros((k, 0))
        x, c = b.x[:, 0], b.c[:, 0]
        bag.write_block(self.est, F64_ARRAY, t, self.enc_est(x))
        bag.write_block(self.est_st, JOINT_STATE, t, self.enc_est_st(sec, nsec, x, none, none))
        bag.write_block(self.conv, F64_ARRAY, t,
                        self.enc_conv(np.where(np.isfinite(c), c, -1.0)))
        self.counts[self.est] += k
        self.counts[self.est_st] += k
        self.counts[self.conv] += k
        if self.ui is not None and b.w.shape[2]:
            rows = np.flatnonzero(~np.isnan(b.w[:, 0, 0]))
            if rows.size:
                w = b.w[rows, 0]
                bag.write_block(self.ui, F64_ARRAY, t[rows], self.enc_ui(w))
                bag.write_block(self.ui_st, JOINT_STATE, t[rows],
                                self.enc_ui_st(sec[rows], nsec[rows], w, none[rows], none[rows]))
                self.counts[self.ui] += rows.size
                self.counts[self.ui_st] += rows.size
        if self.js is not None and self.js_map is not None:
            names, idx = self.js_map
            fields = [x[:, ix] if ix is not None else none for ix in idx]
            enc = self.enc.joint_state_block(names, tuple(f.shape[1] for f in fields), self.frame)
            bag.write_block(self.js, JOINT_STATE, t, enc(sec, nsec, *fields))
            self.counts[self.js] += k
        self.published += k

    # -- diagnostics --------------------------------------------------------------------
    def diagnostics(self, t_ns: int, received: dict, side: str = "left"):
        """``runner.status`` at ``t_ns`` (bag time), written to /diagnostics as the node
        publishes it, with the replay's equivalents of the node's own counters; the status."""
        statuses = self.runner.statuses(t_ns / 1e9)
        st = statuses[0]
        if t_ns >= MAX_STAMP_NS:            # no header stamp can say that time
            return st
        values = list(st.values) + [
            ("enabled", "true"), ("source", self.settings["source"]),
            *((f"messages received: {k}", str(int(np.searchsorted(v, t_ns, side))))
              for k, v in received.items()),
            ("estimates published", str(self.published)), ("sim time", "true (offline replay)")]
        # with joints, the node's status, then one per joint (after the node's values)
        self.bag.diagnostics("/diagnostics", t_ns, [{
            "level": st.level, "name": self.diag_name, "message": st.message,
            "hardware_id": self.hw_id, "values": values}] + [{
                "level": js.level, "name": f"{self.diag_name}: {joint}", "message": js.message,
                "hardware_id": self.hw_id, "values": js.values}
                for joint, js in zip(self.runner.joints, statuses[1:])])
        self.counts["/diagnostics"] = self.counts.get("/diagnostics", 0) + 1
        level = LEVEL_NAMES.get(st.level, str(st.level))
        self.status_levels[level] = self.status_levels.get(level, 0) + 1
        return st
