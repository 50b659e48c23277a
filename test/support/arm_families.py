"""Build the arm's external-torque families (external_torque, momentum_observer) and feed
them samples, for the tests: through the runner's own reading of the parameters
(runner/settings.py ``split``), so a test builds exactly what the node and the replay
build; streams of an arm's JointState in the intake's layout."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fto_ros.runner.runner import Runner
from fto_ros.runner.settings import split

ROOT = Path(__file__).resolve().parents[2]
PANDA = ROOT / "urdf" / "panda_gripper.urdf"
ARM7 = ROOT / "urdf" / "arm7.urdf"
PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
ARM7_JOINTS = [f"joint_a{i}" for i in range(1, 8)]


def flat(family: str, urdf=None, text=None, joints=(), **params) -> dict:
    """The flat parameters of ``family`` on a URDF file or text; ``params`` with '__' for
    '.' (external_torque__window=0.03)."""
    out = {"observer.type": family, "joints": list(joints)}
    if urdf is not None:
        out["plant.urdf"] = str(urdf)
    if text is not None:
        out["robot_description"] = text
    out.update({k.replace("__", "."): v for k, v in params.items()})
    return out


def observer(family: str, urdf=None, text=None, joints=(), **params):
    """The family's adapter, built as the runner builds it."""
    settings, cls, cfg = split(flat(family, urdf, text, joints, **params))
    return cls(cfg)


def runner(family: str, urdf=None, text=None, joints=(), **params) -> Runner:
    return Runner(flat(family, urdf, text, joints, **params))


def samples(run, obs, columns=None):
    """(y (N, n), u (N, n + k)) of an ArmRun (fto_ros/models/arm.py) for ``obs``: the
    measured positions and the efforts of its joints, the passive joints' positions."""
    names = list(run.names)
    ci = [names.index(j) for j in obs.joints]
    pi = [names.index(j) for j in obs.passive_joints]
    effort = run.effort if hasattr(run, "effort") and run.effort is not None else run.tau
    y = run.q_measured[:, ci]
    u = np.hstack([effort[:, ci], run.q_measured[:, pi]])
    return y, u
