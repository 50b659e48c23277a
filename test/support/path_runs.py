"""Committed (bag, config) pairs run through ``Runner.process_block``, here and in a
subprocess on the numpy path (FTO_ROS_NUMBA=0), to compare the compiled kernels with it.

``run_pairs(pairs, limit)`` replays the first ``limit`` messages of each pair's bag (inputs
and measurements, in log-time order, inputs first at equal stamps) and returns per pair the
block's statuses, estimates and convergence values; ``numpy_path(pairs, limit, tmp)`` does
the same in a fresh interpreter with numba off.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _events(bag: Path, runner, limit: int):
    from fto_ros.bag import BagReader
    from fto_ros.replay.topics import resolve_topic
    from fto_ros.runner import loop as L
    s = runner.settings
    meas = resolve_topic(s["topics.measured_output"], "/observer_node")
    inp = resolve_topic(s["topics.input"], "/observer_node") if runner.observer.n_inputs else None
    ev = []
    with BagReader(bag) as b:
        for topic, t_ns, msg in b.messages([meas] + ([inp] if inp else [])):
            ev.append((t_ns, topic != inp, [float(v) for v in msg.data]))
            if len(ev) >= limit:
                break
    ev.sort(key=lambda e: (e[0], e[1]))
    t0 = ev[0][0]
    kind = np.array([L.MEASUREMENT if m else L.INPUT for _, m, _ in ev], np.int8)
    width = max(len(v) for _, _, v in ev)
    values = np.zeros((len(ev), width))
    for i, (_, _, v) in enumerate(ev):
        values[i, :len(v)] = v
    return kind, np.array([(e[0] - t0) / 1e9 for e in ev]), values


def run_pairs(pairs, limit: int) -> dict[str, np.ndarray]:
    """{f"{i}_status" | "_est" | "_conv": array} for pair i of ``pairs`` ([bag, [params]])."""
    from fto_ros.runner import Runner
    from fto_ros.runner.params_file import load_params_files
    out = {}
    for i, (bag, params) in enumerate(pairs):
        r = Runner(load_params_files([str(ROOT / p) for p in params]))
        kind, t, values = _events(ROOT / "bags" / bag, r, limit)
        blk = r.process_block(kind, t, values)
        status, est, conv = blk.status[:, 0], blk.estimate[:, 0], blk.convergence[:, 0]
        out[f"{i}_status"], out[f"{i}_est"], out[f"{i}_conv"] = status, est, conv
    return out


def numpy_path(pairs, limit: int, tmp: Path) -> dict[str, np.ndarray]:
    """``run_pairs`` in a subprocess with numba off."""
    target = tmp / "numpy_path.npz"
    env = dict(os.environ, FTO_ROS_NUMBA="0")
    subprocess.run([sys.executable, __file__, str(target), str(limit), json.dumps(pairs)],
                   check=True, env=env, cwd=ROOT, timeout=1800)
    with np.load(target) as data:
        return dict(data)


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    np.savez(sys.argv[1], **run_pairs(json.loads(sys.argv[3]), int(sys.argv[2])))
