"""The replay loop: the bag's messages in log-time order through the runner, exactly as the
live node would take them, and the node's outputs written to the output bag (the timed
part of a replay).

One concern per module: replay/streams.py reads the bag (which topic plays which role,
the messages), replay/events.py orders them and cuts them into windows (at the
diagnostics boundaries), replay/blocks.py runs a window through the runner (the block
interface), replay/outputs.py writes the copies, the estimates and /diagnostics.  This
module ties them together and times the parts.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..bag import BagWriter
from ..bag.reader import deserialize, shared_typestore
from ..runner.runner import Runner, convergence_fields
from ..runner.sources import make_source
from . import events as E
from .blocks import OutputBlock, plan_rows, run_window, ui_width
from .outputs import OutputBag
from .streams import Inputs, read_inputs

#: zstd level of the output bag: compressing is the largest part of writing it, and
#: level 1 takes half the time of the default 3 for a 7 % larger file (docs/replay.md)
OUTPUT_ZSTD_LEVEL = 1
#: the data topics whose messages /diagnostics counts, as the node does
RECEIVED = ("measured_output", "input", "joint_states")
#: the most events the runner is handed at once (a window also ends at every diagnostics
#: boundary); bounds the memory of a window's outputs
MAX_WINDOW_EVENTS = 1 << 14


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
    """What the replay loop produced: the inputs read, every accepted sample's outputs
    (arrays, one row per sample), counts, statuses, timing."""

    inputs: Inputs | None = None
    est_t: np.ndarray = None            # (k,) int64 sample times
    est_x: np.ndarray = None            # (k, n): the first joint's (the whole plant's)
    est_conv: np.ndarray = None         # (k, ncf)
    est_ui_idx: np.ndarray = None       # (m,) rows of est_* with an unknown-input estimate
    est_ui: np.ndarray = None           # (m, r)
    est_ok: np.ndarray = None           # (k, J) the joint has an output in the row
    est_xj: np.ndarray = None           # (k, J, n) every joint's estimates
    est_cj: np.ndarray = None           # (k, J, ncf) ... convergence values
    est_w: np.ndarray = None            # (k, J, r) ... unknown inputs
    proc_s: np.ndarray = None           # (k,) s: the update time of each row (gather)
    counts: dict = field(default_factory=dict)
    status_levels: dict = field(default_factory=dict)
    final_status: Any = None
    source: Any = None
    timing: dict = field(default_factory=dict)

    def gather(self, blocks: list[OutputBlock], n: int, r: int, ncf: int, J: int) -> None:
        """The rows of every window's block, in order (one joint: the joint axis dropped)."""
        cat = (lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape))
        self.est_t = cat([b.t_ns for b in blocks], 0).astype(np.int64)
        x = cat([b.x for b in blocks], (0, J, n))
        c = cat([b.c for b in blocks], (0, J, ncf))
        w = cat([b.w for b in blocks], (0, J, r))
        self.est_ok = cat([b.ok for b in blocks], (0, J)).astype(bool)
        # the update time of a sample: its window's runner time over the window's samples
        self.proc_s = cat([np.full(b.t_ns.size, b.runner_s / max(b.status.shape[0], 1))
                           for b in blocks], 0)
        self.est_xj, self.est_cj, self.est_w = x, c, w
        self.est_x, self.est_conv = x[:, 0], c[:, 0]
        has_w = self.est_ok[:, 0] if r else np.zeros(x.shape[0], bool)
        self.est_ui_idx = np.flatnonzero(has_w)
        self.est_ui = w[has_w, 0]


class _RosbagsFallback:
    """The replay's fallback for what the numpy codec does not take: rosbags' deserialiser
    (BagError naming the bag and the topic for what it refuses too: a bad bag stops the
    replay).  ``roles``: the topic of each source key, once the bag's roles are known."""

    def __init__(self, bag_path: Path):
        self.bag_path, self.roles = bag_path, {}

    def __call__(self, payload: bytes, msgtype: str, key: str):
        where = f"{self.bag_path}: topic {self.roles.get(key, key)}"
        return deserialize(shared_typestore(), payload, msgtype, where, 0)


def bag_rows(runner: Runner, bag_path: Path, fqn: str):
    """(source, inputs, rows): the runner's rows of every message ``runner`` reads from the
    bag, planned as the replay plans them (fto-tune scores candidates on them)."""
    fallback = _RosbagsFallback(bag_path)
    source = make_source(runner, fallback)
    inp = read_inputs(bag_path, runner, fqn, source)
    fallback.roles = inp.roles
    ev = E.order_events(inp.streams, {t.key: t.rank for t in source.topics})
    return source, inp, plan_rows(source, ev, inp.streams)


def _run(runner: Runner, bag_path: Path, out_dir: Path, fqn: str, overwrite: bool,
         progress: bool, custom: dict[str, str], protect: tuple = ()) -> _Run:
    """Read the bag, drive the runner, write the output bag (the timed part); the output
    bag never replaces, lies inside or holds a path of ``protect`` (the inputs)."""
    settings, obs = runner.settings, runner.observer
    r = _Run()
    wall0 = time.perf_counter()
    fallback = _RosbagsFallback(bag_path)
    source = make_source(runner, fallback)
    r.inputs = inp = read_inputs(bag_path, runner, fqn, source)
    fallback.roles = inp.roles
    streams, info = inp.streams, inp.info
    wall_read = time.perf_counter()
    ev = E.order_events(streams, {t.key: t.rank for t in source.topics})
    rows = plan_rows(source, ev, streams)
    wall_order = time.perf_counter()

    n, ncf = obs.n_states, len(convergence_fields(obs))
    period_ns = max(int(round(settings["diagnostics.period"] * 1e9)), 1)
    received = {key: streams.times(key) for key in RECEIVED}
    t_first = int(ev.t[0]) if ev.t.size else info.start_ns
    t_last = int(ev.t[-1]) if ev.t.size else info.end_ns
    bar = _Progress(progress, t_first, t_last)
    Path(out_dir).parent.mkdir(parents=True, exist_ok=True)   # --out a/b/c: make a/b
    runner_s = 0.0
    blocks: list[OutputBlock] = []
    wall_loop0 = time.perf_counter()
    with BagWriter(out_dir, overwrite=overwrite, custom_data=custom, inputs=protect,
                   level=OUTPUT_ZSTD_LEVEL) as bag:
        out = OutputBag(bag, runner, source.plan, fqn, inp)
        r_ui = ui_width(runner)
        for start, stop, boundary in E.windows(ev, t_first, period_ns, MAX_WINDOW_EVENTS):
            block = run_window(runner, rows, start, stop)
            runner_s += block.runner_s
            out.copy(ev, start, stop)
            out.publish(block)
            blocks.append(block)
            if boundary is not None:
                out.diagnostics(boundary, received)
            if stop:
                bar.update(int(ev.t[stop - 1]))
        r.final_status = out.diagnostics(t_last, received, "right")
        bar.done()
        wall_loop1 = time.perf_counter()
    wall_end = time.perf_counter()
    r.gather(blocks, n, r_ui, ncf, runner.n_joints)
    r.counts, r.status_levels = out.counts, out.status_levels
    r.source = source
    r.timing = {
        "read_decode": wall_read - wall0,
        # ordering the events and making the runner's rows of them (the intake)
        "order_events": wall_order - wall_read,
        "runner": runner_s,
        "serialize_write": (wall_loop1 - wall_loop0) - runner_s,
        "close_output": wall_end - wall_loop1,
        "replay_total": wall_end - wall0,
    }
    return r
