"""A slow reference for fto-identify written from the equations, not from the package:
the direct form of the dynamics at every sample,

    tau - armature a = sum_l f_l Y_l(q, v, a) theta_l + b v + f_c tanh(v / w),

with Pinocchio's joint-torque regressor (computeJointTorqueRegressor: the joint torques per
unit of each body's 10 inertia parameters) giving each link's column Y_l theta_l at its URDF
inertia, velocities and accelerations by central differences of the positions (noise-free
data: a second difference would amplify any noise by 1 / h^2), and the torque held over
each sample interval averaged across the sample, (tau_(k-1) + tau_k) / 2 (the central
difference sees the mean acceleration over [t_(k-1), t_(k+1)]); ordinary least squares.
Uniform stamps only. Nothing from fto_ros's numerics (only its test URDF text)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin


def fit_scales_and_friction(text: str, t, q, tau, armature, width: float):
    """(factor per joint's body, viscous, Coulomb) of a chain whose every joint moves one
    link (the test arm), by least squares on the direct form (module doc)."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    t, q, tau = (np.asarray(x, dtype=float) for x in (t, q, tau))
    h = float(np.mean(np.diff(t)))
    assert np.allclose(np.diff(t), h, rtol=1e-9), "the naive reference wants uniform stamps"
    v = (q[2:] - q[:-2]) / (2 * h)
    a = (q[2:] - 2 * q[1:-1] + q[:-2]) / h ** 2
    qk = q[1:-1]
    y = 0.5 * (tau[:-2] + tau[1:-1]) - np.asarray(armature) * a
    n = q.shape[1]
    theta = [model.inertias[j].toDynamicParameters() for j in range(1, model.njoints)]
    rows, cols = [], []
    for k in range(len(qk)):
        Y = pin.computeJointTorqueRegressor(model, data, qk[k], v[k], a[k])
        links = [Y[:, 10 * j:10 * j + 10] @ theta[j] for j in range(n)]
        fric = [np.eye(n)[:, i] * v[k, i] for i in range(n)] + \
            [np.eye(n)[:, i] * np.tanh(v[k, i] / width) for i in range(n)]
        cols.append(np.stack(links + fric, axis=1))
        rows.append(y[k])
    A, b = np.concatenate(cols), np.concatenate(rows)
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    return x[:n], x[n:2 * n], x[2 * n:]
