"""``arm_kalman`` (observers/arm_kalman; docs/arm.md): the Kalman filter on the arm's URDF
model through its adapter and the runner: it beats the backward difference on a simulated
arm, every effort meaning drives the same prediction, the disturbance torque finds a push,
gaps are predicted across (longer ones refused), the refusals name the parameter, and the
numpy path equals the compiled kernel.  ROS-free."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from arm_families import ARM7, ARM7_JOINTS, feed, observer
from fto_ros.arm import load_model
from fto_ros.core.errors import ConfigError
from fto_ros.models.arm import ArmSettings, Contact, simulate_arm
from fto_ros.observers import REGISTRY
from fto_ros.observers.base import SampleRejected

ROOT = Path(__file__).resolve().parents[3]
FAMILY = "arm_kalman"


def simulate(duration=2.0, seed=5, contacts=()):
    urdf = load_model(ARM7_JOINTS, urdf=ARM7)
    return simulate_arm(urdf, ArmSettings(duration=duration, seed=seed, contacts=list(contacts)),
                        nominal=urdf)


@pytest.fixture(scope="module")
def pushed():
    return simulate(contacts=[Contact("link_4", 1.0, 0.5, (0, 80, 0))])


def _arm(**params):
    return observer(FAMILY, ARM7, joints=ARM7_JOINTS, **params)


def test_registered_and_its_layout():
    obs = _arm()
    assert REGISTRY[FAMILY] is type(obs)
    assert obs.n_states == 14 and obs.n_outputs == 7 and obs.n_inputs == 7
    assert obs.state_names[7] == "joint_a1_dot" and obs.unknown_input_names == ARM7_JOINTS


def test_beats_the_backward_difference_and_finds_the_push(pushed):
    """Exact model: the velocity error under half the difference's on every joint in free
    motion (after 0.3 s, outside the push and 0.3 s after its start and end); late in the
    push the disturbance torque d shows the external torque."""
    r = pushed
    obs = _arm()
    D, V, _ = feed(obs, r.t, r.q_measured, r.tau)
    keep = (r.t >= 0.3) & ~((r.t >= 1.0) & (r.t < 1.3)) & ~((r.t >= 1.5) & (r.t < 1.8))
    rms = np.sqrt(np.mean((V[keep] - r.v[keep]) ** 2, axis=0))
    bd = np.diff(r.q_measured, axis=0) / np.diff(r.t)[:, None]
    rms_bd = np.sqrt(np.mean((bd[keep[1:]] - r.v[1:][keep[1:]]) ** 2, axis=0))
    assert np.all(rms < 0.5 * rms_bd), (rms, rms_bd)
    late = (r.t >= 1.3) & (r.t < 1.5)
    err = np.abs(D[late] - r.tau_ext[late]).max(axis=0)
    assert np.all(err < 0.2 * np.abs(r.tau_ext[late]).max() + 0.5), err


def test_every_effort_meaning_drives_the_same_prediction(pushed):
    """commanded_no_gravity (the kernel adds g(q)) and current (torque = current k_t gear)
    give the commanded torque's estimate."""
    r = pushed
    N = 400
    model = load_model(ARM7_JOINTS, urdf=ARM7)
    g = np.array([model.gravity(q) for q in r.q_measured[:N]])
    base = feed(_arm(), r.t[:N], r.q_measured[:N], r.tau[:N])[1]
    nog = feed(_arm(effort__meaning="commanded_no_gravity"), r.t[:N], r.q_measured[:N],
               r.tau[:N] - g)[1]
    cur = feed(_arm(effort__meaning="current", effort__torque_constant=[0.5],
                    effort__gear_ratio=[100.0]), r.t[:N], r.q_measured[:N], r.tau[:N] / 50.0)[1]
    np.testing.assert_allclose(nog, base, rtol=0, atol=1e-9)
    np.testing.assert_allclose(cur, base, rtol=0, atol=1e-9)


def test_gaps_are_predicted_across_and_longer_ones_refused(pushed):
    r = pushed
    obs = _arm(arm_kalman__max_step=0.02)
    keep = np.ones(r.t.size, bool)
    keep[500:510] = False                          # an 11 ms gap: predicted in sub-steps
    D, V, _ = feed(obs, r.t[keep], r.q_measured[keep], r.tau[keep])
    after = np.flatnonzero(keep)[500:520]
    assert np.abs(V[500:520] - r.v[after]).max() < 0.05
    assert obs.diagnostics()["gaps predicted across"] == "1"
    before = obs._st.copy()
    with pytest.raises(SampleRejected):
        obs.update(float(r.t[-1] + 0.05), r.q_measured[-1], r.tau[-1])
    assert np.array_equal(obs._st, before, equal_nan=True)


@pytest.mark.parametrize("change, parameter", [
    (dict(arm_kalman__disturbance_rate=[1.0, 2.0]), "arm_kalman.disturbance_rate"),
    (dict(arm_kalman__encoder_noise=[0.0]), "arm_kalman.encoder_noise"),
    (dict(arm_kalman__max_step=1e-4), "arm_kalman.max_step"),
])
def test_refusals_name_the_parameter(change, parameter):
    with pytest.raises(ConfigError, match=parameter.replace(".", r"\.")):
        _arm(**change)


_NUMPY_PATH = """
import sys, numpy as np
sys.path[:0] = [{support!r}, {here!r}]
from test_arm_kalman import simulate, _arm
from arm_families import feed
r = simulate(duration=0.3)
D, V, _ = feed(_arm(), r.t, r.q_measured, r.tau)
np.save({out!r}, np.hstack([D, V]))
"""


def test_numpy_path_equals_the_compiled_kernel(tmp_path):
    """arm_kalman's kernel on the numpy path (FTO_ROS_NUMBA=0) against the compiled one."""
    from fto_ros.core import jit
    if not jit.ENABLED:
        pytest.skip("numba is off in this run: the compiled side cannot be compared")
    out = tmp_path / "numpy.npy"
    env = dict(os.environ, FTO_ROS_NUMBA="0")
    code = _NUMPY_PATH.format(support=str(ROOT / "test" / "support"),
                              here=str(Path(__file__).parent), out=str(out))
    subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=ROOT, timeout=900)
    r = simulate(duration=0.3)
    D, V, _ = feed(_arm(), r.t, r.q_measured, r.tau)
    np.testing.assert_allclose(np.load(out), np.hstack([D, V]), rtol=1e-9, atol=1e-9)


def test_the_detector_on_d_calibrates_without_a_false_mismatch(pushed):
    """Calibrated on the free motion before the push: every joint armed with a finite
    guaranteed detection of a 10 Nm step; the exact model raises no mismatch at the example
    configs' factor (6; the measured level is 2-4.4x the encoder's)."""
    r = pushed
    N = int(np.searchsorted(r.t, 0.95))
    obs = _arm(collision__calibration=0.8, collision__mismatch_factor=6.0)
    feed(obs, r.t[:N], r.q_measured[:N], r.tau[:N])
    diag = obs.joint_diagnostics()
    assert [e["state"] for e in diag] == ["armed"] * 7
    assert all(np.isfinite(float(e["guaranteed detection of 10 Nm (ms)"])) for e in diag)
    assert obs.warnings() == []
