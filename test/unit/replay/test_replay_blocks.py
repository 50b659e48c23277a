"""The replay's block interface to the runner (replay/blocks.py, replay/events.py): the
rows of a window go through Runner.process_block in one call, a window's OutputBlock says
for every sample what the runner did with it, and windows end at the diagnostics
boundaries."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from fto_ros.bag import BagWriter
from fto_ros.replay import events as E
from fto_ros.replay.blocks import ACCEPTED, IS_HELD, REJECTED, plan_rows, run_window
from fto_ros.replay.streams import read_inputs
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files
from fto_ros.runner.sources import make_source

ROOT = Path(__file__).resolve().parents[3]


def _bag(path: Path) -> Path:
    """2 s of a DC-motor-shaped stream at 1 kHz with junk in it: NaN, a wrong length, a
    repeated stamp, a jump far ahead and back (held, then dropped)."""
    with BagWriter(path) as bag:
        for k in range(2000):
            t = 10 ** 9 + k * 10 ** 6
            bag.float_array("/dc_motor/input", t, [2.0])
            y = [0.5 + 1e-3 * k]
            if k == 300:
                y = [float("nan")]
            elif k == 400:
                y = [1.0, 2.0]
            bag.float_array("/dc_motor/measured_output", t, y)
            if k == 500:
                bag.float_array("/dc_motor/measured_output", t, y)
            if k == 600:
                bag.float_array("/dc_motor/measured_output", t + 10 ** 12, y)
            bag.float_array("/dc_motor/true_state", t, [y[0], 0.0, 0.0])
    return path


def test_every_sample_has_a_status_and_the_rows_are_the_accepted_ones(tmp_path):
    runner = Runner(load_params_files(params_files(ROOT / "config" / "dc_motor_luenberger.yaml")))
    source = make_source(runner)
    inp = read_inputs(_bag(tmp_path / "junk"), runner, "/observer_node", source)
    ev = E.order_events(inp.streams, {t.key: t.rank for t in source.topics})
    rows = plan_rows(source, ev, inp.streams)
    obs = runner.observer
    blocks = []
    period = 10 ** 8
    due = []
    calls = []
    orig = runner.process_block
    runner.process_block = lambda *a: calls.append(len(a[1])) or orig(*a)
    for start, stop, boundary in E.windows(ev, int(ev.t[0]), period, 128):
        block = run_window(runner, rows, start, stop)
        assert len(calls) == len(blocks) + 1 or start == stop   # one compiled call a window
        blocks.append(block)
        if boundary is not None:
            due.append(boundary)
            assert ev.t[stop] >= boundary > ev.t[stop - 1] if stop > start else True
        assert stop - start <= 128
    status = np.concatenate([b.status for b in blocks])
    assert status.size == inp.streams.times("measured_output").size              # one per sample, in order
    assert int((status == ACCEPTED).sum()) == runner.accepted
    assert Counter(r for b in blocks for r in b.reasons) == runner.rejected
    assert int((status == REJECTED).sum()) == sum(runner.rejected.values())
    assert int((status == IS_HELD).sum()) >= 1                  # the jump ahead was held
    t_acc = np.concatenate([b.t_ns for b in blocks])
    assert t_acc.size == runner.accepted and np.all(np.diff(t_acc) > 0)
    x = np.concatenate([b.x for b in blocks])
    assert x.shape == (runner.accepted, 1, obs.n_states) and np.isfinite(x).all()
    # one diagnostics boundary per 0.1 s of the bag (the jump ahead is one event: the
    # boundaries after it are skipped to the first one past it)
    assert due == sorted(set(due)) and len(due) >= 19
