"""The naive single-delay observer of Mazenc & Malisoff 2022 (the paper's equations, plain
numpy/scipy), shared by test_naive_single_delay.py and the acquirer of test_naive_track.py.

The DC motor of Section V in the paper's coordinates (eq. 66-67): xi1 = (q_dot, I),
xi2 = q = Y,  xi1' = A1 xi1 + F1(Y, u),  xi2' = A2 xi1 + G(Y),  A1 = [[-a2, b1], [-a3, -a4]],
A2 = [1, 0], F1 = (-a1 sin Y, b0 V), G = 0; the observer's F2 = G + k Y.

- design (eq. 4-6): lambda(r) = A2 (A1 + kI)^-1 [I - e^{(A1 + kI) r}],
  S = int_{-tau}^0 lambda' lambda, N = int_{-tau}^0 lambda', R = S^-1 N,
  H = ((A1 + kI)^-1)' A2'; the integrals by scipy's adaptive Gauss-Kronrod (quad_vec) to
  1e-14 relative;
- the dynamic extension (7), z = (xh1, xh2, psi1, psi2):
      xh1' = A1 xh1 + F1,  xh2' = A2 xh1 - k xh2 + F2,
      psi1' = -k psi1 + H (Y - xh2),  psi2' = -(A1' + 2kI) psi2 + H (Y - xh2);
- the estimate (13) for t >= tau after the start:
      xi_e = xh1 + R (Y - xh2) + S^-1 [e^{-k tau} psi1(t - tau) - psi1(t)]
                               + S^-1 [psi2(t) - e^{-(A1' + 2kI) tau} psi2(t - tau)],
  before that the model copy xh1 (docs/single_delay.md: no guarantee before tau);
- start: xh1 = 0, xh2 = Y(t0), psi = 0.
"""
from __future__ import annotations

import bisect

import numpy as np
from scipy.integrate import quad_vec, solve_ivp
from scipy.linalg import expm

import naive_plants as NP
import naive_support as NS

DC = NP.DC
A1 = np.array([[-DC["a2"], DC["b1"]], [-DC["a3"], -DC["a4"]]])
A2 = np.array([[1.0, 0.0]])


def F1(Y, u):
    return np.array([-DC["a1"] * np.sin(Y[0]), DC["b0"] * u[0]])


class Design:
    """S, N, R, H of eq. (4)-(6) for gain k and delay tau."""

    def __init__(self, k: float, tau: float):
        n1 = A1.shape[0]
        self.k, self.tau = k, tau
        Mk = A1 + k * np.eye(n1)
        Mi = np.linalg.inv(Mk)

        def lam(r):
            return A2 @ Mi @ (np.eye(n1) - expm(Mk * r))
        self.S = quad_vec(lambda r: lam(r).T @ lam(r), -tau, 0.0, epsabs=0.0, epsrel=1e-14)[0]
        self.N = quad_vec(lambda r: lam(r).T, -tau, 0.0, epsabs=0.0, epsrel=1e-14)[0]
        self.Si = np.linalg.inv(self.S)
        self.R = self.Si @ self.N
        self.H = Mi.T @ A2.T
        self.E1 = np.exp(-k * tau)                        # e^{-k tau}
        self.E2 = expm(-(A1.T + 2 * k * np.eye(n1)) * tau)
        self.cond = np.linalg.cond(self.S)

    def extension(self):
        """(Az, Bz) of z' = Az z + Bz w, z = (xh1, xh2, psi1, psi2), w = (F1, F2, Y)."""
        n1, q, k = A1.shape[0], A2.shape[0], self.k
        N = 3 * n1 + q
        Az = np.zeros((N, N))
        Bz = np.zeros((N, n1 + 2 * q))
        i1, i2, p1, p2 = slice(0, n1), slice(n1, n1 + q), slice(n1 + q, 2 * n1 + q), slice(2 * n1 + q, N)
        Az[i1, i1] = A1
        Bz[i1, :n1] = np.eye(n1)                           # + F1
        Az[i2, i1] = A2
        Az[i2, i2] = -k * np.eye(q)
        Bz[i2, n1:n1 + q] = np.eye(q)                      # + F2
        Az[p1, p1] = -k * np.eye(n1)
        Az[p1, i2] = -self.H                               # H (Y - xh2)
        Bz[p1, n1 + q:] = self.H
        Az[p2, p2] = -(A1.T + 2 * k * np.eye(n1))
        Az[p2, i2] = -self.H
        Bz[p2, n1 + q:] = self.H
        return Az, Bz

    def estimate(self, z, Y, z_delayed):
        """xi_e of eq. (13) from z(t), Y(t) and z(t - tau)."""
        n1, q = A1.shape[0], A2.shape[0]
        xh1, xh2 = z[:n1], z[n1:n1 + q]
        psi1, psi2 = z[n1 + q:2 * n1 + q], z[2 * n1 + q:]
        d1, d2 = z_delayed[n1 + q:2 * n1 + q], z_delayed[2 * n1 + q:]
        return (xh1 + self.R @ (Y - xh2) + self.Si @ (self.E1 * d1 - psi1)
                + self.Si @ (psi2 - self.E2 @ d2))


class Continuous:
    """The continuous form one sample at a time, on a regular grid of period h with tau a
    whole number of periods (the delayed values are then samples of this run):
    ``first(Y, u)``, then ``take(Y, u_held)`` (u_held: the input over the interval);
    ``estimate`` = (q, q_dot, I) = (Y, xi_e); ``samples`` since the start."""

    def __init__(self, design: "Design", h: float):
        self.d, self.h = design, h
        self.lag = round(design.tau / h)
        assert abs(self.lag * h - design.tau) < 1e-12, "tau must be a whole number of periods"
        self.Az, self.Bz = design.extension()

    def _w(self, Y, u):
        return np.concatenate((F1(Y, u), self.d.k * Y, Y))   # (F1, F2 = G + k Y, Y)

    def first(self, Y, u):
        n1 = A1.shape[0]
        z = np.zeros(self.Az.shape[0])
        z[n1:n1 + 1] = Y
        self.zs, self.Y, self.u = [z], Y, u
        return self._publish()

    def take(self, Y, u_held):
        # w linear over the interval, the input held (the end value of F1 too)
        z = NS.linear_hold_step(self.Az, self.Bz, self.zs[-1], self._w(self.Y, u_held),
                                self._w(Y, u_held), self.h)
        self.zs.append(z)
        self.Y = Y
        return self._publish()

    @property
    def samples(self):
        return len(self.zs)

    def _publish(self):
        j, z = len(self.zs) - 1, self.zs[-1]
        xi = self.d.estimate(z, self.Y, self.zs[j - self.lag]) if j >= self.lag else z[:A1.shape[0]]
        self.estimate = np.concatenate((self.Y, xi))
        return self.estimate


def continuous_reference(design: Design, t, y, u):
    """The published estimate (q, q_dot, I) at every stamp (regular stamps)."""
    h = NS.steps(t)
    assert np.all(h == h[0]), "regular stamps"
    obs = Continuous(design, h[0])
    out = [obs.first(y[0], u[0])]
    for j in range(1, len(t)):
        out.append(obs.take(y[j], u[j - 1]))
    return np.array(out)


def sampled_reference(design: Design, t, y, u, rtol: float = 1e-11):
    """Theorem 2 (eq. 39): between the samples the predictor omega' = A2 xi_e - k omega +
    F2(omega) stands in for Y (reset to Y at each sample), the extension driven by omega and
    xi_e by (13) with omega for Y; solved by DOP853 at ``rtol`` on each sample interval,
    the delayed z(t - tau) read from this run's own dense output.  The published estimate
    (q, q_dot, I) = (Y, xi_e) at every stamp."""
    Az, Bz = design.extension()
    n1, N, k, tau = A1.shape[0], Az.shape[0], design.k, design.tau
    t0 = t[0]
    starts, pieces = [], []                                 # (start, end, dense z)

    def z_at(s):
        s = max(s, t0)                  # the read at t0 + tau - 1e-9 falls before the start
        i = max(0, bisect.bisect_right(starts, s) - 1)
        a, b, sol = pieces[i]
        assert a - 1e-12 <= s <= b + 1e-12, f"no history at {s}"
        return sol(min(max(s, a), b))[:N]

    def rhs(s, Z, uu):
        z, om = Z[:N], Z[N:]
        w = np.concatenate((F1(om, uu), k * om, om))
        if s - t0 >= tau - 1e-9:
            xi = design.estimate(z, om, z_at(s - tau))
        else:
            xi = z[:n1]
        return np.concatenate((Az @ z + Bz @ w, A2 @ xi - k * om + k * om))
    z = np.zeros(N)
    z[n1:n1 + 1] = y[0]
    out = [np.concatenate((y[0], z[:n1]))]
    starts.append(t0)
    pieces.append((t0, t0, lambda s, z=z.copy(): np.concatenate((z, y[0]))))
    for j in range(1, len(t)):
        a, b = t0 + round((t[j - 1] - t0) * 1e6) * 1e-6, t0 + round((t[j] - t0) * 1e6) * 1e-6
        # split at t0 + tau, where the predictor's right-hand side switches to (13)
        cut = [a] + [c for c in (t0 + tau,) if a < c < b] + [b]
        Z = np.concatenate((z, y[j - 1]))
        for lo, hi in zip(cut[:-1], cut[1:]):
            sol = solve_ivp(rhs, (lo, hi), Z, method="DOP853", rtol=rtol, atol=rtol * 1e-3,
                            dense_output=True, args=(u[j - 1],))
            starts.append(lo)
            pieces.append((lo, hi, sol.sol))
            Z = sol.y[:, -1]
        z = Z[:N]
        xi = design.estimate(z, y[j], z_at(b - tau)) if b - t0 >= tau - 1e-9 else z[:n1]
        out.append(np.concatenate((y[j], xi)))
    return np.array(out)
