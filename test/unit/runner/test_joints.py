"""Joints as an axis (runner/joints.py): one observer of a one-joint plant per joint, all in
one compiled call per message.  Each joint's estimates equal those of a runner of that joint
alone, bit for bit; one joint's junk (a NaN, a refused entry) rejects that joint only."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.core.reasons import CODE
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parents[3]
A1 = [35.0, 30.0, 40.0]


def _base(tuning="dc_motor_luenberger"):
    return load_params_files([ROOT / "config/dc_motor_plant.yaml", ROOT / f"config/{tuning}.yaml"],
                             "observer_node")


def _with_a1(flat, value):
    f = dict(flat)
    f["plant.constants"] = [f"a1={value}" if c.startswith("a1=") else c for c in flat["plant.constants"]]
    return f


def _multi(flat, joints=("j1", "j2", "j3"), a1=A1):
    f = dict(flat)
    f["joints"] = list(joints)
    f["source"] = "joint_states"
    f["plant.constants"] = [("a1=[" + ", ".join(map(str, a1)) + "]") if c.startswith("a1=") else c
                            for c in flat["plant.constants"]]
    return f


def _streams(n=1500):
    t = np.arange(n) * 1e-3
    y = np.sin(t[:, None] * np.array([1.0, 2.0, 3.0]))
    u = np.cos(t[:, None] * np.array([1.0, 0.5, 0.2]))
    return t, y, u


@pytest.mark.parametrize("tuning", ["dc_motor_luenberger", "dc_motor_luenberger_poles"])
def test_each_joint_equals_its_own_runner_bit_for_bit(tuning):
    base = _base(tuning)
    multi = Runner(_multi(base))
    alone = [Runner(_with_a1(base, a)) for a in A1]
    t, y, u = _streams()
    y[400, 1] = math.nan                          # junk on joint j2 only
    refused = np.zeros((len(t), 3), np.int16)
    refused[700, 2] = CODE["joint_states_joint_missing"]
    for k in range(len(t)):
        outs = multi.process_joints(t[k], y[k][:, None], u[k][:, None], refused[k])
        for j, r in enumerate(alone):
            if refused[k, j]:
                r.reject("joint_states_joint_missing")
                want = "joint_states_joint_missing"
            else:
                assert r.set_input(t[k], [u[k, j]]) is None
                want = r.process(t[k], [y[k, j]])
            got = outs[j]
            if isinstance(want, str):
                assert got == want, (k, j)
            else:
                assert np.array_equal(got.estimate, want.estimate), (k, j)
                assert np.array_equal(got.convergence, want.convergence), (k, j)
    for j, r in enumerate(alone):
        assert multi.rejected_of(j) == r.rejected
        assert int(multi._mem.rs[j, 11]) == r.accepted          # loop.ACCEPTED
    assert multi.rejected_of(0) == {}
    levels = [st.level for st in multi.statuses(1.5)]
    assert levels[1] == 0 and levels[2] > 0 and levels[3] > 0 and levels[0] == max(levels[1:])


def test_roles_and_refusals():
    base = _base()
    r = Runner(_multi(base))
    assert [(x.position, x.velocity, x.effort) for x in r.roles] == [(0, 1, ("none", -1))] * 3
    bad = _multi(base)
    bad["plant.constants"] = ["a1=[1, 2]" if c.startswith("a1=") else c for c in bad["plant.constants"]]
    with pytest.raises(ConfigError, match=r"plant.constants\[2\].*2 value\(s\) for 3 joint"):
        Runner(bad)
    dup = _multi(base, joints=("j1", "j1", "j3"))
    with pytest.raises(ConfigError, match="listed twice"):
        Runner(dup)
    topics = _multi(base)
    topics["source"] = "topics"
    with pytest.raises(ConfigError, match="source"):
        Runner(topics)
    role = _multi(base)
    role["joint_roles.velocity_state"] = "nope"
    with pytest.raises(ConfigError, match="joint_roles.velocity_state"):
        Runner(role)
