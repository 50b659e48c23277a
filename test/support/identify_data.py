"""Simulated recordings for fto-identify's tests: a small arm (a 3-joint chain with rotor
inertias, test/support/arm_urdfs.py) whose true inertias, friction and payload differ from
its URDF in known ways, driven by models/arm.py's simulator (RK4, the torque held between
samples, the encoder's noise), and the prior model the identification starts from."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arm_urdfs import chain, inertial, joint, link
from fto_ros.arm import load_model
from fto_ros.models.arm import ArmSettings, Contact, simulate_arm

TEXT = chain(3)
JOINTS = ["j1", "j2", "j3"]
ARMATURE = [0.05, 0.05, 0.03]
VISCOUS = [0.6, 0.8, 0.7]
COULOMB = [0.5, 0.9, 0.7]
SCALE = {"l1": 1.06, "l2": 0.95, "l3": 1.04}
#: the Coulomb friction's smooth sign tanh(v / WIDTH): wide enough that the velocity between
#: two samples stays nearly linear through a reversal (the sample period resolves it)
WIDTH = 0.1
#: a centre of mass moved and a moment changed (link axes, about the link's origin)
DELTA = {"l2": [0.0, 0.004, -0.003, 0.006, 0.002, 0.0, 0.001, 0.0, 0.0, 0.0],
         "l3": [0.0, -0.002, 0.005, 0.003, 0.0, 0.0015, 0.0, 0.0, 0.0, 0.0]}


def urdf_with_armature() -> str:
    """TEXT with the rotor inertias written in the URDF (``<dynamics armature>``), for
    ``fto-simulate --urdf``, which takes them from the file."""
    parts = ['<robot name="chain">', link("l0")]
    for i in range(1, 4):
        parts.append(joint(f"j{i}", "revolute", f"l{i - 1}", f"l{i}", (0, 0, 0.1), (0.1, 0, 0),
                           (0, i % 2, (i + 1) % 2),
                           f'<dynamics armature="{ARMATURE[i - 1]!r}"/>'))
        parts.append(link(f"l{i}", inertial(1.0, (0, 0, 0.05))))
    return "".join(parts + ["</robot>"])


@dataclass
class Recording:
    t: np.ndarray
    q: np.ndarray             # the encoder's
    tau: np.ndarray           # the torque commanded at each sample (held until the next)
    truth: object             # the true model
    run: object


def prior(**kw):
    """The URDF's model as the identification gets it (its rotor inertias known)."""
    return load_model(JOINTS, robot_description=TEXT, armature=ARMATURE, friction_width=WIDTH,
                      **kw)


def true_model(scale=None, delta=None, viscous=VISCOUS, coulomb=COULOMB, payload=None):
    model = load_model(JOINTS, robot_description=TEXT, armature=ARMATURE,
                       viscous_friction=viscous, coulomb_friction=coulomb,
                       friction_width=WIDTH, inertia_scale=scale, inertia_delta=delta)
    if payload is not None:
        model.set_payload(*payload)
    return model


def record(model, duration=3.0, seed=0, noise=1e-5, resolution=0.0, jitter=0.0,
           amplitude=(0.6, 0.5, 0.7), period=(2.1, 1.7, 1.3), contacts=()) -> Recording:
    """Simulate ``model`` (the true arm) under a PD on the prior's gravity."""
    settings = ArmSettings(duration=duration, seed=seed, noise=noise, resolution=resolution,
                           jitter=jitter, q0=(0.2, 0.4, -0.3), amplitude=tuple(amplitude),
                           period=tuple(period),
                           contacts=[Contact(*c) for c in contacts])
    run = simulate_arm(model, settings, nominal=prior())
    return Recording(t=run.t, q=run.q_measured, tau=run.tau, truth=model, run=run)
