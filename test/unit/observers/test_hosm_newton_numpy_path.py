"""hosm and newton_inversion: the compiled kernels and the numpy path (FTO_ROS_NUMBA=0, the
same kernel code run as Python) give the same outputs on every committed config of the two
families, on the first samples of a committed bag of each.

Measured: exactly equal (statuses, estimates, unknown-input estimates, convergence values),
except newton_inversion's health figure cond(J): numpy's np.linalg.cond (LAPACK's SVD) on
the numpy path, a one-sided Jacobi SVD compiled (observers/newton_inversion/numerics.py),
within 1e-12 relative (measured up to 2e-14 on the replays).  The numpy side runs in one
subprocess (numba is chosen at import).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core import jit

ROOT = Path(__file__).resolve().parents[3]
#: (bag, config): every committed hosm and newton_inversion config
PAIRS = [("dc_motor_load", "dc_motor_hosm"), ("fld_example1", "fld_example1_hosm"),
         ("fld_example2", "fld_example2_hosm"), ("msd_disturbed", "msd_hosm"),
         ("dc_motor_noisy", "dc_motor_newton"), ("msd", "msd_newton"),
         ("possieri_example_sinusoid", "possieri_example_newton"),
         ("possieri_example_sinusoid", "possieri_example_newton_ndim"),
         ("possieri_example_sinusoid", "possieri_example_newton_notch")]
SAMPLES = 1500
HEALTH = 4            # the health figure's place among the convergence values


def run_pairs() -> dict[str, np.ndarray]:
    """Per pair: the status of every call (0 output, else a rejection code), and the
    estimate, unknown-input estimate and convergence values of every output."""
    from fto_ros.bag.reader import read_messages
    from fto_ros.core.reasons import CODE
    from fto_ros.runner import Runner
    from fto_ros.runner.params_file import load_params_files
    from fto_ros.runner.plant_files import params_files
    out = {}
    for bag, cfg in PAIRS:
        flat = load_params_files(params_files(ROOT / "config" / f"{cfg}.yaml"))
        runner = Runner(flat)
        y_topic, u_topic = (runner.settings[f"topics.{k}"] for k in ("measured_output", "input"))
        status, est, ui, conv = [], [], [], []
        taken = 0
        topics = [y_topic] + ([u_topic] if runner.observer.n_inputs else [])
        for topic, t_ns, msg in read_messages(ROOT / "bags" / bag, topics):
            t = t_ns * 1e-9
            if topic == u_topic:
                runner.set_input(t, list(msg.data))
                continue
            r = runner.process(t, list(msg.data))
            if isinstance(r, str):
                status.append(CODE.get(r, -1))
            else:
                status.append(0)
                est.append(r.estimate)
                ui.append(r.unknown_input if r.unknown_input is not None else np.zeros(0))
                conv.append(r.convergence)
            taken += 1
            if taken == SAMPLES:
                break
        out[cfg + "/status"] = np.array(status)
        out[cfg + "/est"], out[cfg + "/ui"], out[cfg + "/conv"] = map(np.array, (est, ui, conv))
    return out


@pytest.mark.skipif(not jit.ENABLED, reason="numba is off here (FTO_ROS_NUMBA=0): no compiled "
                    "path to compare the numpy path with")
def test_compiled_and_numpy_paths_agree(tmp_path):
    compiled = run_pairs()
    target = tmp_path / "numpy.npz"
    env = dict(os.environ, FTO_ROS_NUMBA="0")
    subprocess.run([sys.executable, __file__, str(target)], cwd=ROOT, env=env, check=True)
    pure = dict(np.load(target))
    assert sorted(pure) == sorted(compiled)
    for bag, cfg in PAIRS:
        np.testing.assert_array_equal(compiled[cfg + "/status"], pure[cfg + "/status"], cfg)
        assert (compiled[cfg + "/status"] == 0).sum() > SAMPLES // 2, cfg   # outputs to compare
        for part in ("est", "ui"):
            np.testing.assert_array_equal(compiled[f"{cfg}/{part}"], pure[f"{cfg}/{part}"],
                                          f"{cfg}: {part}")
        a, b = compiled[cfg + "/conv"], pure[cfg + "/conv"]
        if "newton" in cfg:
            np.testing.assert_allclose(a[:, HEALTH], b[:, HEALTH], rtol=1e-12, atol=0,
                                       err_msg=f"{cfg}: cond(J)")
            a, b = np.delete(a, HEALTH, axis=1), np.delete(b, HEALTH, axis=1)
        np.testing.assert_array_equal(a, b, f"{cfg}: convergence")


if __name__ == "__main__":          # the numpy side, in a process of its own
    np.savez(sys.argv[1], **run_pairs())
