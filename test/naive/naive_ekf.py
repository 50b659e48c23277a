"""The naive continuous-discrete EKF (docs/ekf.md, the textbook filter; test_naive_ekf.py
states the equations), one sample at a time, shared by test_naive_ekf.py and the tracker of
test_naive_track.py; the DC motor's f and Jacobian (config/dc_motor_plant.yaml)."""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm

import naive_plants as NP
import naive_support as NS

DC = NP.DC


def dc_f(x, u):
    return NP.dc_motor_rhs(x, u)


def dc_jacobian(x, u):
    return np.array([[0.0, 1.0, 0.0],
                     [-DC["a1"] * np.cos(x[0]), -DC["a2"], DC["b1"]],
                     [0.0, -DC["a3"], -DC["a4"]]])


def predict(x, P, u, dt, Qc, f, jac):
    n = len(x)
    A = jac(x, u)
    Mx = np.zeros((n + 1, n + 1))
    Mx[:n, :n] = A
    Mx[:n, n] = f(x, u)
    x_new = x + expm(Mx * dt)[:n, n]
    V = np.block([[-A, Qc], [np.zeros((n, n)), A.T]]) * dt
    E = expm(V)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    return x_new, Phi @ P @ Phi.T + (Qd + Qd.T) / 2


class Filter:
    """The filter one sample at a time (h(x) = H x): ``start(x, P)``, then ``take(dt, y, u)``
    (predict over dt with u held, correct with y; dt = 0: correct only); ``x``, ``nis``."""

    def __init__(self, Qc, R, max_step, f, jac, H):
        self.Qc, self.R, self.max_step, self.f, self.jac, self.H = Qc, R, max_step, f, jac, H

    def start(self, x, P):
        self.x, self.P, self.nis = np.asarray(x, float), np.asarray(P, float), np.nan

    def take(self, dt, y, u):
        if dt > 0:
            subs = int(np.ceil(dt / self.max_step - 1e-9))
            for _ in range(subs):
                self.x, self.P = predict(self.x, self.P, u, dt / subs, self.Qc, self.f, self.jac)
        H, P, n = self.H, self.P, len(self.x)
        nu = y - H @ self.x
        S = H @ P @ H.T + self.R
        Si = np.linalg.inv(S)
        K = P @ H.T @ Si
        self.x = self.x + K @ nu
        IKH = np.eye(n) - K @ H
        P = IKH @ P @ IKH.T + K @ self.R @ K.T
        self.P = (P + P.T) / 2
        self.nis = float(nu @ Si @ nu)
        return self.x


def ekf_reference(t, y, u, Qc, R, P0, max_step, f, jac, H):
    """x_hat at every stamp (see the module doc), from the start on the first measurement."""
    n = H.shape[1]
    Hp = np.linalg.pinv(H)
    N = np.eye(n) - Hp @ H
    kf = Filter(Qc, R, max_step, f, jac, H)
    kf.start(Hp @ y[0], Hp @ R @ Hp.T + N @ P0 @ N.T)
    out = [kf.x]
    for k, dt in enumerate(NS.steps(t)):
        out.append(kf.take(dt, y[k + 1], u[k]))
    return np.array(out)
