"""The naive robust exact differentiator with the eigenvalue-matched discretisation
(docs/differentiator.md, Koch & Reichhartinger 2018), shared by the hosm and
newton_inversion references.

Chain of length N = n + 1 (z_0 ~ f, ..., z_n ~ f^(n)), |f^(N)| <= L, pole scale
r = rho L^(1/N).  One step over h from z with the sample f:

    e = f - z_0,  w = 1 - exp(-h r |e|^(-1/N))  (w = 1 when e = 0)
    z+ = Phi(h) z + lambda e,   Phi(h) the Taylor shift (Phi_ij = h^(j-i) / (j-i)!),
    lambda such that every eigenvalue of Phi(h) - lambda e_1' is 1 - w

lambda by Ackermann's formula for the pair (Phi, e_1'), lambda = p(Phi) O^-1 e_N with
p(s) = (s - 1 + w)^N, computed in h-scaled coordinates
(zeta_i = h^i z_i, where Phi has the entries 1 / (j-i)! and the observability matrix is
well conditioned whatever h), then lambda_i = lambda_bar_i / h^i.

The recursion: at the k-th sample the state is advanced over h_k with the previous
sample's innovation; the published estimate is the next prediction made with the new
sample, shifted back over the same step: z+_k = Phi(h_k)^-1 step(z_k, f_k, h_k)
(docs/differentiator.md, "The estimate at t uses the sample at t").  Start: z = (f_0, 0, ...).
"""
from __future__ import annotations

import math

import numpy as np


def shift_bar(N: int) -> np.ndarray:
    return np.array([[1.0 / math.factorial(j - i) if j >= i else 0.0 for j in range(N)]
                     for i in range(N)])


def matched_gain_bar(N: int, w: float) -> np.ndarray:
    """lambda_bar (h-scaled) placing every eigenvalue of Phi_bar - lambda_bar e_1' at 1 - w."""
    Pb = shift_bar(N)
    O = np.vstack([np.linalg.matrix_power(Pb, i)[0] for i in range(N)])
    # p(Phi_bar) = (Phi_bar - (1 - w) I)^N = (S + w I)^N, S = Phi_bar - I strictly upper
    # triangular: built with w on the diagonal, no cancellation (the expanded polynomial's
    # coefficients are O(N choose k) and would cancel to w^N)
    pA = np.linalg.matrix_power(Pb - np.eye(N) + w * np.eye(N), N)
    e_n = np.zeros(N)
    e_n[-1] = 1.0
    return pA @ np.linalg.solve(O, e_n)


class Differentiator:
    def __init__(self, order: int, L: float, rho: float):
        self.N = order + 1
        self.r = rho * L ** (1.0 / self.N)
        self.Pb = shift_bar(self.N)
        self.Pb_inv = np.linalg.inv(self.Pb)

    def _step(self, z, f, h):
        scale = h ** np.arange(self.N)
        e = f - z[0]
        w = -math.expm1(-h * self.r * abs(e) ** (-1.0 / self.N)) if e != 0 else 1.0
        zb = self.Pb @ (z * scale) + matched_gain_bar(self.N, w) * e
        return zb / scale

    def reset(self, f0: float) -> np.ndarray:
        self.z = np.zeros(self.N)
        self.z[0] = f0
        self.f = f0
        self.estimate = self.z.copy()
        return self.estimate

    def update(self, h: float, f: float) -> np.ndarray:
        self.z = self._step(self.z, self.f, h)
        scale = h ** np.arange(self.N)
        ahead = self._step(self.z, f, h)
        self.estimate = (self.Pb_inv @ (ahead * scale)) / scale
        self.f = f
        return self.estimate
