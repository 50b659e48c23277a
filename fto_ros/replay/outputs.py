"""The replay's output bag: the input topics copied as read, what the node publishes for
each accepted sample (the source's output plan, runner/sources/plan.py), and /diagnostics,
written a block at a time.

Every output message has a fixed layout per set of joints, so a block of k samples is
encoded as one (k, L) byte array (core/cdr.py, through the plan: the node's layouts) and
written as one block per topic (bag/writer.py): no Python per message.  Log time and
header stamp of an output = its sample time, as the node stamps them.
"""
from __future__ import annotations

import numpy as np

from ..bag import BagWriter
from ..runner.status import LEVEL_NAMES
from .blocks import OutputBlock

#: log times from here on cannot be header stamps (int32 seconds)
MAX_STAMP_NS = 2 ** 31 * 1_000_000_000


class OutputBag:
    """Writes one replay's outputs into ``bag`` (an open BagWriter): ``plan`` the source's."""

    def __init__(self, bag: BagWriter, runner, plan, fqn: str, inp):
        settings = runner.settings
        self.bag, self.runner, self.settings, self.plan = bag, runner, settings, plan
        self.streams = streams = inp.streams
        self.counts: dict[str, int] = {}
        self.status_levels: dict[str, int] = {}
        # the input topics, copied (log times as in the input bag): the output bag holds
        # what the estimates were estimated from, and plays on its own
        self.copy_topic = dict(inp.roles)
        self.types = inp.types
        for role, topic in self.copy_topic.items():
            bag.connect(topic, self.types[role])
            self.counts[topic] = len(streams.raw[role][1])
        self._cursor = {role: 0 for role in self.copy_topic}
        self.topics = [f"{fqn}/{spec.topic}" for spec in plan.specs]
        for topic, spec in zip(self.topics, plan.specs):
            bag.connect(topic, spec.msgtype)
            self.counts[topic] = 0
        bag.connect("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        # as the node: status name "<node name>: observer", hardware_id defaults to the type
        self.diag_name = f"{fqn.rsplit('/', 1)[-1]}: observer"
        self.hw_id = settings["diagnostics.hardware_id"] or runner.observer_type
        self.published = 0

    # -- copies -------------------------------------------------------------------------
    def copy(self, ev, start: int, stop: int) -> None:
        """Copy the input messages of the events ``[start, stop)`` (each stream's next ones)."""
        per_kind = np.bincount(ev.kind[start:stop], minlength=len(ev.roles))
        for kind, role in enumerate(ev.roles):
            n = int(per_kind[kind])
            if not n or role not in self.copy_topic:
                continue
            lo = self._cursor[role]
            t, payloads = self.streams.raw[role]
            part = payloads.matrix[lo:lo + n] if getattr(payloads, "matrix", None) is not None \
                else [payloads[k] for k in range(lo, lo + n)]
            self.bag.write_block(self.copy_topic[role], self.types[role], t[lo:lo + n], part)
            self._cursor[role] = lo + n

    # -- estimates ----------------------------------------------------------------------
    def publish(self, b: OutputBlock) -> None:
        """Write what the node publishes for the samples of ``b`` with an output."""
        k = b.t_ns.size
        if not k:
            return
        for i, (topic, spec) in enumerate(zip(self.topics, self.plan.specs)):
            for rows, payloads in self.plan.encode_block(i, b.t_ns, b.x, b.w, b.c, b.ok):
                self.bag.write_block(topic, spec.msgtype, b.t_ns[rows], payloads)
                self.counts[topic] += rows.size
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
