"""The compiled dynamics (fto_ros/arm/dynamics.py) against Pinocchio's algorithms
(arm/pin_reference.py) on random configurations of urdf/arm7.urdf and of a random arm with a
mimic-finger gripper and a passive side joint (test/support/arm_urdfs.py); the Coriolis
identities; the numpy path (FTO_ROS_NUMBA=0) against the compiled one.

Tolerances: the recursions' round-off is a few eps times the number of joints times the
depth of the tree, relative to the largest intermediate product, which the scales below
bound (||M|| for M; ||M|| ||v|| for C and Mdot, linear in v with dM/dq ~ M per radian or
metre; ||M|| (||a|| + ||v||^2) + ||g|| for torques; the reach for Jacobians). 1e-10 of the
scale leaves a margin of 1e4-1e5 over what was measured (about 1e-15)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from arm_urdfs import gripper_arm
from fto_ros.arm.model import ArmInputError, load_model
from fto_ros.arm.pin_reference import PinocchioReference

ROOT = Path(__file__).resolve().parents[3]
ARM7 = (ROOT / "urdf" / "arm7.urdf").read_text()
REL = 1e-10

CASES = {
    # the committed arm: every joint listed, the URDF's armature
    "arm7": (ARM7, None, ["link_3", "link_7", "joint_a5"]),
    # listed in a shuffled order; the fingers (finger_2 a mimic of finger_1, -1, 0.01) and
    # the camera's pan joint passive; continuous, prismatic and an oblique axis in the chain
    "gripper_passive": (gripper_arm(1), ["joint_2", "joint_1", "joint_3", "joint_5", "joint_4"],
                        ["tcp", "finger_link_2", "hand_joint", "camera", "link_4"]),
    # the first finger listed: its mimic moves with it (v_2 = -0.5 v_1)
    "gripper_finger_listed": (gripper_arm(2, multiplier=-0.5, offset=0.02),
                              ["joint_1", "joint_2", "finger_1", "joint_3", "joint_4",
                               "joint_5"], ["finger_link_2", "tcp", "camera"]),
}


def build(case):
    text, joints, frames = CASES[case]
    model = load_model(joints, robot_description=text)
    return model, PinocchioReference(model, text), frames


def samples(model, seed, count=6):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield (rng.uniform(-2.5, 2.5, model.n), rng.normal(0, 1.5, model.n),
               rng.normal(0, 3.0, model.n), rng.uniform(-0.04, 0.04, len(model.passive_joints)))


def close(got, want, scale, rel=REL):
    err = np.abs(np.asarray(got) - np.asarray(want)).max()
    assert err <= rel * scale, (err, scale)
    return err / scale


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_term_equals_pinocchios(case):
    model, ref, frames = build(case)
    worst = 0.0
    for k, (q, v, a, p) in enumerate(samples(model, sorted(CASES).index(case))):
        M = ref.mass_matrix(q, p)
        sM = np.linalg.norm(M)
        sC = sM * np.linalg.norm(v)
        C = ref.coriolis_matrix(q, v, p)
        g = ref.gravity(q, p)
        sT = sM * (np.linalg.norm(a) + np.linalg.norm(v) ** 2) + np.linalg.norm(g)
        worst = max(worst, close(model.mass_matrix(q, p), M, sM))
        worst = max(worst, close(model.coriolis_matrix(q, v, p), C, sC))
        worst = max(worst, close(model.gravity(q, p), g, sT))
        worst = max(worst, close(model.coriolis(q, v, p), C @ v, sT))
        worst = max(worst, close(model.bias(q, v, p), C @ v + g, sT))
        worst = max(worst, close(model.inverse_dynamics(q, v, a, p) - model.friction(v),
                                 ref.rnea(q, v, a, p), sT))
        Mt, Md, ctv, gt = model.momentum_terms(q, v, passive=p)
        Mr, Mdr, ctvr, gr = ref.momentum_terms(q, v, passive=p)
        worst = max(worst, close(Mt, Mr, sM), close(Md, Mdr, sC), close(ctv, ctvr, sT),
                    close(gt, gr, sT))
        assert model.momentum_terms(q, v, mass=False, passive=p)[0] is None
        np.testing.assert_array_equal(model.momentum_terms(q, v, False, p)[1], Md)
        for f in frames:
            J = ref.jacobian(f, q, p)
            worst = max(worst, close(model.jacobian(f, q, p), J, max(1.0, np.abs(J).max())))
        a_ref = ref.forward_dynamics(q, v, a, p)
        tau = model.inverse_dynamics(q, v, a_ref, p)
        close(model.forward_dynamics(q, v, tau, p), a_ref, np.linalg.norm(a_ref) *
              np.linalg.cond(M), rel=1e-12)
    assert worst < 1e-13          # measured: a few 1e-15


@pytest.mark.parametrize("case", sorted(CASES))
def test_coriolis_identities(case):
    """Mdot - 2 C is skew; Mdot is dM/dt along v (central difference); C v is the bias
    less gravity; C' v = Mdot v - C v; M is symmetric positive definite."""
    model, _, _ = build(case)
    h = 1e-6
    for q, v, _, p in samples(model, 7, 4):
        M = model.mass_matrix(q, p)
        np.testing.assert_array_equal(M, M.T)
        assert np.linalg.eigvalsh(M)[0] > 0
        C = model.coriolis_matrix(q, v, p)
        _, Md, ctv, g = model.momentum_terms(q, v, passive=p)
        sC = np.linalg.norm(M) * np.linalg.norm(v)
        N = Md - 2 * C
        close(N, -N.T, sC, 1e-12)
        fd = (model.mass_matrix(q + h * v, p) - model.mass_matrix(q - h * v, p)) / (2 * h)
        close(Md, fd, sC, 1e-7)
        close(C @ v, model.bias(q, v, p) - g, sC * np.linalg.norm(v), 1e-12)
        close(ctv, C.T @ v, sC * np.linalg.norm(v), 1e-12)


def test_wrong_sizes_are_refused_by_name():
    model, _, _ = build("gripper_passive")
    with pytest.raises(ArmInputError, match="positions: need 5"):
        model.mass_matrix(np.zeros(4))
    with pytest.raises(ArmInputError, match=r"passive positions: need 2 values \(finger_1, pan\)"):
        model.gravity(np.zeros(5), passive=np.zeros(3))


NUMPY_PATH = """
import json, sys
import numpy as np
sys.path.insert(0, {support!r})
from arm_urdfs import gripper_arm
from fto_ros.core import jit
from fto_ros.arm.model import load_model
m = load_model({joints!r}, robot_description=gripper_arm(2, multiplier=-0.5, offset=0.02))
rng = np.random.default_rng(3)
q, v, a = (rng.normal(0, 1, m.n) for _ in range(3))
p = np.array([0.01, 0.3][:len(m.passive_joints)])
out = dict(M=m.mass_matrix(q, p), C=m.coriolis_matrix(q, v, p),
           tau=m.inverse_dynamics(q, v, a, p), J=m.jacobian("finger_link_2", q, p))
out = {{k: x.tolist() for k, x in out.items()}}
out["terms"] = [x.tolist() for x in m.momentum_terms(q, v, passive=p)]
out["numba"] = jit.ENABLED
print(json.dumps(out))
"""


def test_the_numpy_path_computes_the_same_terms():
    """The same code with numba off (FTO_ROS_NUMBA=0, plain Python) and on."""
    code = NUMPY_PATH.format(support=str(ROOT / "test" / "support"),
                             joints=CASES["gripper_finger_listed"][1])
    runs = {}
    for flag in ("0", "1"):
        res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                             text=True, env=dict(os.environ, FTO_ROS_NUMBA=flag), timeout=600)
        assert res.returncode == 0, res.stderr[-2000:]
        runs[flag] = json.loads(res.stdout.strip().splitlines()[-1])
    assert runs["0"]["numba"] is False
    for key in ("M", "C", "tau", "J"):
        a, b = np.array(runs["0"][key]), np.array(runs["1"][key])
        close(a, b, np.abs(b).max(), 1e-13)
    for a, b in zip(runs["0"]["terms"], runs["1"]["terms"]):
        close(np.array(a), np.array(b), np.abs(np.array(b)).max(), 1e-13)
