"""The compiled single_delay kernels and their numpy path (FTO_ROS_NUMBA=0) give the same
outputs, bit for bit, on every committed single_delay config (with its first committed bag:
both forms, both plants): this process runs one path, a subprocess the other.  (Each path
also reproduces every pair's reference exactly: test_kernel_reference.py.)"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

import reference_runs as RR
from fto_ros.core import jit

_, META = RR.load_reference()
PAIRS = list({p["params"][-1]: p for p in reversed(META["pairs"])
              if "single_delay" in p["params"][-1]}.values())
HERE = Path(__file__).resolve().parent
SUPPORT = HERE.parents[1] / "support"     # reference_runs, for the subprocess


def replay_outputs(pairs) -> dict[str, np.ndarray]:
    """Every call's status and every output of each pair's replay."""
    out = {}
    for i, p in enumerate(pairs):
        log, _ = RR.log_replay(RR.ROOT / "bags" / p["bag"], [RR.ROOT / f for f in p["params"]])
        status, est, ui, conv = RR.outputs(log, 1)
        out[f"{i}_status"] = np.array(status)
        out[f"{i}_est"], out[f"{i}_ui"], out[f"{i}_conv"] = est, ui, conv
    return out


def test_compiled_and_numpy_paths_agree_on_every_committed_config(tmp_path):
    assert {p["params"][-1].rsplit("/", 1)[-1] for p in PAIRS} >= {
        "dc_motor_single_delay.yaml", "dc_motor_single_delay_sampled.yaml", "msd_single_delay.yaml"}
    other = tmp_path / "other.npz"
    code = (f"import sys, json, numpy as np; sys.path[:0] = [{str(HERE)!r}, {str(SUPPORT)!r}]\n"
            "from test_single_delay_paths import replay_outputs\n"
            "np.savez(sys.argv[2], **replay_outputs(json.loads(sys.argv[1])))\n")
    env = dict(os.environ, FTO_ROS_NUMBA="0" if jit.ENABLED else "1")
    subprocess.run([sys.executable, "-c", code, json.dumps(PAIRS), str(other)], cwd=RR.ROOT,
                   env=env, check=True)
    theirs = np.load(other)
    ours = replay_outputs(PAIRS)
    assert sorted(theirs.files) == sorted(ours)
    for key, mine in ours.items():
        assert np.array_equal(mine, theirs[key], equal_nan=mine.dtype.kind == "f"), \
            f"{PAIRS[int(key.split('_')[0])]['bag']} {key}: the two paths differ"
