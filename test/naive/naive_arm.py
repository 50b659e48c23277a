"""What the naive references of the arm's external-torque families share: the arm's terms
from Pinocchio (M = crba, C = computeCoriolisMatrix, g = computeGeneralizedGravity on its
own reading of urdf/arm7.urdf, the armature and friction read from the XML's <dynamics>,
which urdfdom ignores in part), a stream to feed both sides, and the detector's levels
(docs/external_torque.md, "Collision detection") written again.

Nothing here imports the package's numerics: the package is reached through its runner.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
from scipy.stats import chi2, norm

from naive_support import ROOT

URDF = ROOT / "urdf" / "arm7.urdf"
JOINTS = [f"joint_a{i}" for i in range(1, 8)]


class Arm:
    """M(q), C(q, v), g(q) of arm7's joints (Pinocchio), the armature on M's diagonal, the
    URDF's viscous and Coulomb friction (width 0.02 rad/s)."""

    def __init__(self):
        import pinocchio as pin
        self.pin = pin
        self.model = pin.buildModelFromUrdf(str(URDF))
        self.data = self.model.createData()
        dyn = {j.get("name"): j.find("dynamics") for j in ET.parse(URDF).getroot().iter("joint")}
        self.armature = np.array([float(dyn[j].get("armature", 0)) for j in JOINTS])
        self.b = np.array([float(dyn[j].get("damping", 0)) for j in JOINTS])
        self.fc = np.array([float(dyn[j].get("friction", 0)) for j in JOINTS])
        self.model.armature = self.armature.copy()
        self.width = 0.02
        ids = [self.model.getJointId(j) for j in JOINTS]
        assert [self.model.joints[i].idx_v for i in ids] == list(range(7))

    def M(self, q):
        M = np.array(self.pin.crba(self.model, self.data, np.asarray(q, float)))
        return np.triu(M) + np.triu(M, 1).T

    def C(self, q, v):
        return np.array(self.pin.computeCoriolisMatrix(self.model, self.data,
                                                       np.asarray(q, float), np.asarray(v, float)))

    def g(self, q):
        return np.array(self.pin.computeGeneralizedGravity(self.model, self.data,
                                                           np.asarray(q, float)))

    def rnea(self, q, v, a):
        return np.array(self.pin.rnea(self.model, self.data, np.asarray(q, float),
                                      np.asarray(v, float), np.asarray(a, float)))


def stream(arm: Arm, n: int, seed: int = 1, jitter_us: int = 100, gaps=()):
    """(t, q, tau): n samples of a smooth motion at 1 kHz, stamps jittered by up to
    ``jitter_us`` whole microseconds, the samples at ``gaps`` (indices) left out; positions
    with 1e-5 rad of noise; the torques of the motion (RNEA plus friction) at the samples,
    with 0.05 Nm of noise, and a 10 Nm push on joint 2 from the middle on (the package and
    the reference take the same numbers: the data need not be a physical run)."""
    rng = np.random.default_rng(seed)
    us = np.round(np.arange(n) * 1000 + rng.integers(-jitter_us, jitter_us + 1, n))
    us[0] = 0
    t = 2.0 + us * 1e-6
    w = np.linspace(1.0, 3.0, 7)
    amp = np.linspace(0.5, 0.2, 7)
    q = 0.2 + amp * np.sin(w * t[:, None])
    v = amp * w * np.cos(w * t[:, None])
    a = -amp * w * w * np.sin(w * t[:, None])
    tau = np.array([arm.rnea(q[k], v[k], a[k]) + arm.armature * a[k] + arm.b * v[k]
                    + arm.fc * np.tanh(v[k] / arm.width) for k in range(n)])
    tau[n // 2:, 1] -= 10.0
    tau += rng.normal(0, 0.05, tau.shape)
    q = q + rng.normal(0, 1e-5, q.shape)
    keep = np.ones(n, bool)
    keep[list(gaps)] = False
    return t[keep], q[keep], tau[keep]


def levels(residuals: np.ndarray, scales: np.ndarray, correlation_sum: float,
           bound: float = 1e-2, rate: float = 1000.0, upper_factor: float = 3.0):
    """The lower and upper levels (per joint, in units of the scale) after a calibration
    over ``residuals`` (N x n) divided by ``scales``: z sigma with z from the union bound,
    sigma the RMS at its upper confidence bound (chi-square, 1e-3, with the calibration's
    effective samples N / (1 + 2 sum of the squared autocorrelations))."""
    N, n = residuals.shape
    z = norm.isf(bound / (2 * 3600 * rate * n))
    rms = np.sqrt(np.mean((residuals / scales) ** 2, axis=0))
    nu = N / (1 + 2 * correlation_sum)
    sigma = rms * math.sqrt(nu / chi2.ppf(1e-3, nu))
    return z * sigma, upper_factor * z * sigma
