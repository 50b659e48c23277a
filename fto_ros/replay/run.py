"""The replay loop: the bag's messages in log-time order through the runner, exactly as
the live node would take them, and the node's outputs written to the output bag (the
timed part of a replay)."""
from __future__ import annotations

import functools
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..bag import BagReader, BagWriter
from ..bag.cdr import F64_ARRAY, JOINT_STATE, Encoders
from ..bag.reader import jazzy_typestore
from ..observers.base import Observer
from ..runner.messages import joint_state_sample
from ..runner.runner import LEVEL_NAMES, Runner, convergence_fields
from .streams import _check_topic, _read_streams, _Streams
from .topics import resolve_topic

#: log times from here on cannot be header stamps (int32 seconds)
MAX_STAMP_NS = 2 ** 31 * 1_000_000_000
# event kinds; at equal log times they are processed in this order
K_INPUT, K_MEAS, K_JOINT, K_TRUTH = 0, 1, 1, 2
_KIND_INPUT, _KIND_MEAS, _KIND_JOINT, _KIND_TRUTH, _KIND_CLOCK, _KIND_TRUTH_UI = 0, 1, 2, 3, 4, 5
#: the role each kind copies to the output bag
_COPY_ROLE = {_KIND_INPUT: "inputs", _KIND_MEAS: "meas", _KIND_JOINT: "joints",
              _KIND_TRUTH: "truth", _KIND_CLOCK: "clock", _KIND_TRUTH_UI: "truth_ui"}
CLOCK_TOPIC, CLOCK = "/clock", "rosgraph_msgs/msg/Clock"

class _Progress:
    """A plain ``\\r`` progress bar on stderr, drawn only for replays that take a while."""

    WIDTH = 30

    def __init__(self, enabled: bool, t0_ns: int, t1_ns: int, delay: float = 0.5):
        self.enabled = enabled and sys.stderr.isatty()
        self.t0, self.span = t0_ns, max(t1_ns - t0_ns, 1)
        self.start = time.perf_counter()
        self.delay = delay
        self.drawn = False

    def update(self, t_ns: int) -> None:
        if not self.enabled or time.perf_counter() - self.start < self.delay:
            return
        frac = min(max((t_ns - self.t0) / self.span, 0.0), 1.0)
        fill = int(frac * self.WIDTH)
        sys.stderr.write(f"\rfto-replay [{'#' * fill}{'.' * (self.WIDTH - fill)}] "
                         f"{frac * 100:5.1f}%  {(t_ns - self.t0) / 1e9:.1f} / "
                         f"{self.span / 1e9:.1f} s of bag")
        sys.stderr.flush()
        self.drawn = True

    def done(self) -> None:
        if self.drawn:
            self.update(self.t0 + self.span)
            sys.stderr.write("\n")
            sys.stderr.flush()


@dataclass
class _Run:
    """What the replay loop produced."""

    info: Any = None
    roles: dict = field(default_factory=dict)
    truth_topic: str = ""
    truth_note: str | None = None
    truth_ui_topic: str = ""
    truth_ui_note: str | None = None
    est_ui_idx: list = field(default_factory=list)    # index into est_* of each unknown-input estimate
    est_ui: list = field(default_factory=list)
    streams: _Streams | None = None
    est_t: list = field(default_factory=list)
    est_x: list = field(default_factory=list)
    est_conv: list = field(default_factory=list)
    proc_s: list = field(default_factory=list)
    runner_s: float = 0.0
    counts: dict = field(default_factory=dict)
    status_levels: dict = field(default_factory=dict)
    final_status: Any = None
    fallbacks: list = field(default_factory=list)
    timing: dict = field(default_factory=dict)


def _run(runner: Runner, bag_path: Path, out_dir: Path, fqn: str, overwrite: bool,
         progress: bool, custom: dict[str, str], protect: tuple = ()) -> _Run:
    """Read the bag, drive the runner, write the output bag (the timed part); the output
    bag never replaces, lies inside or holds a path of ``protect`` (the inputs)."""
    settings, obs = runner.settings, runner.observer
    r = _Run()
    wall0 = time.perf_counter()
    with BagReader(bag_path) as reader:
        r.info = info = reader.info()
        topics = info.topics
        roles = r.roles
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
        r.truth_topic = truth_topic = resolve_topic(settings["topics.true_state"], fqn)
        if truth_topic not in topics:
            r.truth_note = f"no ground truth: the bag has no topic {truth_topic}"
        elif topics[truth_topic].msgtype != F64_ARRAY:
            r.truth_note = (f"no ground truth: {truth_topic} is {topics[truth_topic].msgtype}, "
                            f"not {F64_ARRAY}")
        else:
            roles["truth"] = truth_topic
        r.truth_ui_topic = ui_topic = resolve_topic(
            settings.get("topics.true_unknown_input", "true_unknown_input"), fqn)
        if ui_topic in topics and topics[ui_topic].msgtype == F64_ARRAY:
            roles["truth_ui"] = ui_topic
        else:
            r.truth_ui_note = (f"no unknown-input ground truth: the bag has no {F64_ARRAY} "
                               f"topic {ui_topic}")
        if CLOCK_TOPIC in topics and topics[CLOCK_TOPIC].msgtype == CLOCK:
            roles["clock"] = CLOCK_TOPIC                # copied, so the output bag plays alone
        typestore = getattr(reader, "typestore", None) or jazzy_typestore()
        r.streams = streams = _read_streams(bag_path, reader, roles, typestore, topics)
    wall_read = time.perf_counter()

    # events in log-time order; at equal times the clock and inputs, then samples, then the
    # truth (stable)
    parts = [(streams.clock[0], K_INPUT, _KIND_CLOCK), (streams.inputs[0], K_INPUT, _KIND_INPUT),
             (streams.meas[0], K_MEAS, _KIND_MEAS), (streams.joints[0], K_JOINT, _KIND_JOINT),
             (streams.truth[0], K_TRUTH, _KIND_TRUTH), (streams.truth_ui[0], K_TRUTH, _KIND_TRUTH_UI)]
    t_all = np.concatenate([p[0] for p in parts])
    order = np.lexsort((np.concatenate([np.full(p[0].size, p[1], np.int8) for p in parts]), t_all))
    ev_t = t_all[order].tolist()
    ev_kind = np.concatenate([np.full(p[0].size, p[2], np.int8) for p in parts])[order].tolist()
    ev_idx = np.concatenate([np.arange(p[0].size) for p in parts])[order].tolist()
    wall_order = time.perf_counter()

    enc = Encoders(typestore)
    period_ns = max(int(round(settings["diagnostics.period"] * 1e9)), 1)
    # as the node: status name "<node name>: observer", hardware_id defaults to the observer type
    diag_name = f"{fqn.rsplit('/', 1)[-1]}: observer"
    hw_id = settings["diagnostics.hardware_id"] or runner.observer_type
    future_tol_ns = int(round(settings["time.future_tolerance"] * 1e9))
    reject = runner.reject  # as the node does
    received = {"measured_output": streams.meas[0], "input": streams.inputs[0],
                "joint_states": streams.joints[0]}
    t_first = ev_t[0] if ev_t else info.start_ns
    t_last = ev_t[-1] if ev_t else info.end_ns
    tick_ns = max((t_last - t_first) // 200, 1)
    bar = _Progress(progress, t_first, t_last)
    est_t, est_x, est_conv, proc_s = r.est_t, r.est_x, r.est_conv, r.proc_s
    est_ui_idx, est_ui = r.est_ui_idx, r.est_ui
    counts = r.counts
    inputs, meas, joints = streams.inputs[1], streams.meas[1], streams.joints[1]
    set_input, process = runner.set_input, runner.process
    perf = time.perf_counter
    inf = math.inf
    runner_s = 0.0
    Path(out_dir).parent.mkdir(parents=True, exist_ok=True)   # --out a/b/c: make a/b
    wall_loop0 = time.perf_counter()
    with BagWriter(out_dir, overwrite=overwrite, custom_data=custom, inputs=protect) as bag:
        # the input topics, copied as read (log times as in the input bag): the output bag
        # holds what the estimates were estimated from, and plays on its own
        types = {"clock": CLOCK, "joints": JOINT_STATE}
        copy = {}
        for role, topic in roles.items():
            msgtype = types.get(role, F64_ARRAY)
            writer = bag.raw_writer(topic, msgtype) if streams.raw else \
                functools.partial(bag.write_message, topic)
            copy[role] = (writer, streams.copies[role])
            counts[topic] = len(streams.copies[role])
        copy_of = {kind: copy.get(role) for kind, role in _COPY_ROLE.items()}
        # what the node publishes: labelled arrays, stamped estimates (JointState)
        frame = settings["output.frame_id"]
        names = list(obs.state_names)
        w_est = bag.raw_writer(f"{fqn}/state_estimate", F64_ARRAY)
        w_est_st = bag.raw_writer(f"{fqn}/state_estimate_stamped", JOINT_STATE)
        w_conv = bag.raw_writer(f"{fqn}/convergence", F64_ARRAY)
        enc_est = enc.float_array(obs.n_states, names)
        enc_est_st = enc.joint_state(names, (obs.n_states, 0, 0), frame)
        fields = convergence_fields(obs)
        enc_conv = enc.float_array(len(fields), fields, "list")
        w_ui = w_ui_st = w_js = enc_js = None
        if type(obs).unknown_input is not Observer.unknown_input:  # the class identifies one
            ui_names = list(getattr(obs, "unknown_input_names", None) or
                            [f"zeta{j}" for j in range(obs.n_outputs)])
            w_ui = bag.raw_writer(f"{fqn}/unknown_input_estimate", F64_ARRAY)
            w_ui_st = bag.raw_writer(f"{fqn}/unknown_input_estimate_stamped", JOINT_STATE)
            enc_ui = enc.float_array(len(ui_names), ui_names)
            enc_ui_st = enc.joint_state(ui_names, (len(ui_names), 0, 0), frame)
        if settings["estimated_joint_states.joint_names"]:
            w_js = bag.raw_writer(f"{fqn}/estimated_joint_states", JOINT_STATE)
        n_ui = n_js = 0

        def diagnostics(t_ns: int, side: str = "left"):
            st = runner.status(t_ns / 1e9)
            if t_ns >= MAX_STAMP_NS:            # no header stamp can say that time
                return st
            # the node adds its own counters; the replay's equivalents (no wall-clock rates)
            values = list(st.values) + [
                ("enabled", "true"), ("source", settings["source"]),
                *((f"messages received: {k}", str(int(np.searchsorted(v, t_ns, side))))
                  for k, v in received.items()),
                ("estimates published", str(len(est_t))), ("sim time", "true (offline replay)")]
            bag.diagnostics("/diagnostics", t_ns, [{
                "level": st.level, "name": diag_name, "message": st.message,
                "hardware_id": hw_id, "values": values}])
            counts["/diagnostics"] = counts.get("/diagnostics", 0) + 1
            level = LEVEL_NAMES.get(st.level, str(st.level))
            r.status_levels[level] = r.status_levels.get(level, 0) + 1
            return st

        next_diag = t_first + period_ns
        next_tick = min(next_diag, t_first + tick_ns)
        for t_ns, kind, i in zip(ev_t, ev_kind, ev_idx):
            if t_ns >= next_tick:
                if t_ns >= next_diag:
                    # one status per period of bag time; across a forward jump of the log time
                    # one at the first boundary, then the next boundary after the jump: O(1)
                    diagnostics(next_diag)
                    next_diag += period_ns
                    if t_ns >= next_diag:
                        next_diag += (t_ns - next_diag) // period_ns * period_ns + period_ns
                bar.update(t_ns)
                next_tick = min(next_diag, t_ns + tick_ns)
            cp = copy_of[kind]
            if cp is not None:
                cp[0](t_ns, cp[1][i])
            if kind == _KIND_MEAS:
                c0 = perf()
                out = process(t_ns / 1e9, meas[i])
                c1 = perf()
                runner_s += c1 - c0
                if out.__class__ is str:
                    continue
                proc_s.append(c1 - c0)
                s_ns = t_ns
            elif kind == _KIND_INPUT:
                c0 = perf()
                set_input(t_ns / 1e9, inputs[i])
                runner_s += perf() - c0
                continue
            elif kind != _KIND_JOINT:       # the clock, the ground truth: copied only
                continue
            else:  # a JointState (source: joint_states); its sample time is the header stamp
                msg = joints[i]
                c0 = perf()
                sample = joint_state_sample(msg, settings)
                if sample.__class__ is str:
                    reject(sample)
                    runner_s += perf() - c0
                    continue
                t, y, u = sample
                s_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                if s_ns - t_ns > future_tol_ns:  # ahead of the (sim) clock = the log time
                    reject("future_stamp")
                    runner_s += perf() - c0
                    continue
                if u is not None and set_input(t, u) is not None:
                    runner_s += perf() - c0
                    continue  # counted by the runner; never pair y with a bad u
                c1 = perf()
                out = process(t, y)
                c2 = perf()
                runner_s += c2 - c0
                if out.__class__ is str:
                    continue
                proc_s.append(c2 - c1)
            # publish what the node publishes, log time and header stamp = sample time
            x = out.estimate
            est_t.append(s_ns)
            est_x.append(x)
            est_conv.append(out.convergence)
            sec, nsec = s_ns // 1_000_000_000, s_ns % 1_000_000_000
            w_est(s_ns, enc_est(x))
            w_est_st(s_ns, enc_est_st(sec, nsec, x.tolist(), (), ()))
            # as the node: non-finite (guaranteed_time = inf: no guarantee) published as -1.0
            w_conv(s_ns, enc_conv([v if -inf < v < inf else -1.0
                                   for v in out.convergence.tolist()]))
            if out.unknown_input is not None and w_ui is not None:
                ui = np.asarray(out.unknown_input, dtype=np.float64)
                w_ui(s_ns, enc_ui(ui))
                w_ui_st(s_ns, enc_ui_st(sec, nsec, ui.tolist(), (), ()))
                n_ui += 1
                est_ui_idx.append(len(est_t) - 1)
                est_ui.append(ui)
            if out.joint_state is not None and w_js is not None:
                js_names, pos, vel, eff = out.joint_state
                if enc_js is None:
                    enc_js = enc.joint_state(js_names, (len(pos), len(vel), len(eff)), frame)
                w_js(s_ns, enc_js(sec, nsec, pos, vel, eff))
                n_js += 1
        r.final_status = diagnostics(t_last, "right")
        bar.done()
        wall_loop1 = time.perf_counter()
        for topic in ("state_estimate", "state_estimate_stamped", "convergence"):
            counts[f"{fqn}/{topic}"] = len(est_t)
        if w_ui is not None:
            counts[f"{fqn}/unknown_input_estimate"] = counts[f"{fqn}/unknown_input_estimate_stamped"] = n_ui
        if w_js is not None:
            counts[f"{fqn}/estimated_joint_states"] = n_js
    wall_end = time.perf_counter()
    r.runner_s = runner_s
    r.fallbacks = enc.fallbacks
    r.timing = {
        "read_decode": wall_read - wall0,
        "order_events": wall_order - wall_read,
        "runner": runner_s,
        "serialize_write": (wall_loop1 - wall_loop0) - runner_s,
        "close_output": wall_end - wall_loop1,
        "replay_total": wall_end - wall0,
    }
    return r
