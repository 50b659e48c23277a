"""The design quantities of the single-delay observer (Mazenc & Malisoff 2022, eq. 4-6, 11,
15, 38, 41), shared by its continuous and sampled forms: computed once, at construction.

ROS-free.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm


def _gauss_legendre(a: float, b: float, panels: int = 16, order: int = 12):
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(a, b, panels + 1)
    mid = 0.5 * (edges[1:] + edges[:-1])[:, None]
    half = 0.5 * (edges[1:] - edges[:-1])[:, None]
    return (mid + half * x).ravel(), (half * w).ravel()


def _exp(x: float) -> float:
    """exp that saturates to inf: the paper's bounds overflow for large (|A1| + k) tau."""
    return math.exp(x) if x < 700 else math.inf


#: the longest delay (s): the delay buffer holds tau seconds of samples
MAX_TAU = 3600.0
#: largest |eig(A1 + kI)| tau designed: beyond it e^{(A1 + kI) m} over [-tau, 0] has a
#: boundary layer the quadrature cannot see (and overflows further out)
MAX_RATE_TAU = 500.0
#: largest relative change of S, N when the quadrature is refined (quadrature_error)
MAX_QUADRATURE_ERROR = 1e-9


def gramian(A1: np.ndarray, A2: np.ndarray, k: float, tau: float, panels: int = 16):
    """(S, N, lambda at the nodes, nodes, weights): the integrals (5)-(6) over [-tau, 0] by
    composite Gauss-Legendre quadrature, ``panels`` panels of 12 nodes.  The matrix
    exponentials at all nodes are one batched ``expm`` call."""
    I = np.eye(A1.shape[0])
    Ak = A1 + k * I
    G = A2 @ np.linalg.inv(Ak)
    nodes, weights = _gauss_legendre(-tau, 0.0, panels)
    # lambda(m) = G (I - e^{Ak m}) at every node
    lam = G @ (I - expm(Ak * nodes[:, None, None]))                  # (nodes, q, n1)
    S = np.einsum("k,kqi,kqj->ij", weights, lam, lam)
    N = np.einsum("k,kqi->iq", weights, lam)
    return S, N, lam, nodes, weights


def quadrature_error(A1: np.ndarray, A2: np.ndarray, k: float, tau: float, S, N) -> float:
    """Relative change of S and N when the quadrature is refined (twice the panels): the
    a-posteriori error of the design's integrals.  The integrands are sums of exponentials
    e^{eig(A1 + kI) m}; 16 panels resolve them to ~1e-15 while |eig| tau is below ~100."""
    S2, N2, *_ = gramian(A1, A2, k, tau, panels=32)
    return max(float(np.linalg.norm(S - S2) / np.linalg.norm(S2)),
               float(np.linalg.norm(N - N2) / max(np.linalg.norm(N2), 1e-300)))


def design(A1: np.ndarray, A2: np.ndarray, k: float, tau: float) -> dict:
    """S, N, R, H, the decay matrices and the error-bound constants of the paper
    (the integrals: :func:`gramian`)."""
    n1 = A1.shape[0]
    I = np.eye(n1)
    Ak = A1 + k * I
    Aki = np.linalg.inv(Ak)
    G = A2 @ Aki
    S, N, lam, nodes, weights = gramian(A1, A2, k, tau)
    Sinv = np.linalg.inv(S)
    R = Sinv @ N
    H = Aki.T @ A2.T
    E1 = math.exp(-k * tau)
    E2 = expm(-(A1.T + 2 * k * I) * tau)
    norm = lambda M: float(np.linalg.norm(M, 2))  # noqa: E731
    exp = _exp
    lam_norm = np.linalg.norm(lam, 2, axis=(1, 2))
    Sbar, nA1, nA2, nH = norm(Sinv), norm(A1), norm(A2), norm(H)
    eA1 = exp(nA1 * tau)
    # Theorem 2 constants (38): integrals of |lambda(s)| times weights
    s1 = Sbar * nA2 * eA1 / k ** 2 * float(weights @ (lam_norm * (np.exp(k * nodes) - nodes * k - 1)))
    s2 = Sbar / k * float(weights @ (lam_norm * (1 - np.exp(k * nodes))))
    s3 = Sbar * tau * eA1 * nH * float(weights @ (lam_norm * (eA1 + np.exp(-k * nodes))))
    s4 = Sbar * nH * ((1 - math.exp(-k * tau)) / k + tau * exp(norm(A1.T + 2 * k * I) * tau))
    # linear L-infinity gain from the measurement noise delta2 to the estimate error
    # (the part of eq. 32 that does not go through F's Lipschitz constants, plus R delta2(t)):
    # |R| + int_0^tau |S^-1 (e^{-k r} I - e^{-(A1^T + 2kI) r}) H| dr
    r_nodes, r_w = _gauss_legendre(0.0, tau, panels=16, order=8)
    kern = Sinv @ ((np.exp(-k * r_nodes)[:, None, None] * I - expm(-(A1.T + 2 * k * I) * r_nodes[:, None, None])) @ H)
    noise_gain = norm(R) + float(r_w @ np.linalg.norm(kern, 2, axis=(1, 2)))
    beta_star = norm(G) * (1 + exp(norm(Ak) * tau))               # (16)
    beta_2star = 1 + exp(norm(A1.T + 2 * k * I) * tau)             # braces in (15)
    c_delta = tau * Sbar * nA2 * eA1 + Sbar * norm(G) * (eA1 + 1) * eA1  # (11)
    return dict(S=S, N=N, R=R, H=H, Sinv=Sinv, E1=E1, E2=E2, cond_S=float(np.linalg.cond(S)),
                Sbar=Sbar, sigma=(s1, s2, s3, s4), noise_gain=noise_gain, beta_star=beta_star,
                beta_2star=beta_2star, c_delta=c_delta)


def theorem2_mu(d: dict, A2: np.ndarray, k: float, K1: float, K2: float) -> float:
    """mu of (41): Theorem 2 needs T_bar * mu < 1 (a sufficient condition)."""
    s1, s2, s3, s4 = d["sigma"]
    q1 = (s1 + s3) * K1 + s2 * K2 + s4
    return float(np.linalg.norm(A2, 2)) * q1 + k + K2


def noise_bound_constant(d: dict, tau: float, K1: float, K2: float) -> float:
    """c_diamond of Remark 2: |xi1 - xi_e| <= c * sup|(eps1, eps2, delta2)| over the window."""
    return (tau ** 2 * d["beta_star"] * (d["c_delta"] * (K1 + 1) + d["Sbar"] * (K2 + 1))
            + d["Sbar"] * float(np.linalg.norm(d["H"], 2)) * d["beta_2star"] * tau)


def extension(A1: np.ndarray, A2: np.ndarray, k: float, d: dict) -> dict:
    """The linear structure of the dynamic extension (7), state z = [xh1, xh2, psi1, psi2]
    (N = 3 n1 + q) driven by w = [F1, F2, Y] (n1 + 2q):  z' = Az z + Bz w;  the delayed
    combination dl(t) = Md z = S^-1 [e^{-k tau} psi1 - E2 psi2], its derivative MdA z + MdB w,
    and the current part of (13), xi_e = Me z + R Y + dl(t - tau)."""
    n1, q = A1.shape[0], A2.shape[0]
    I1, Iq = np.eye(n1), np.eye(q)
    N = 3 * n1 + q
    x1, x2 = slice(0, n1), slice(n1, n1 + q)
    p1, p2 = slice(n1 + q, 2 * n1 + q), slice(2 * n1 + q, N)
    Az = np.zeros((N, N))
    Az[x1, x1] = A1
    Az[x2, x1] = A2
    Az[x2, x2] = -k * Iq
    Az[p1, x2] = -d["H"]
    Az[p1, p1] = -k * I1
    Az[p2, x2] = -d["H"]
    Az[p2, p2] = -(A1.T + 2 * k * I1)
    Bz = np.zeros((N, n1 + 2 * q))
    Bz[x1, :n1] = I1
    Bz[x2, n1:n1 + q] = Iq
    Bz[p1, n1 + q:] = d["H"]
    Bz[p2, n1 + q:] = d["H"]
    Sinv = d["Sinv"]
    Md = np.zeros((n1, N))
    Md[:, p1] = Sinv * d["E1"]
    Md[:, p2] = -Sinv @ d["E2"]
    Me = np.zeros((n1, N))
    Me[:, x1] = I1
    Me[:, x2] = -d["R"]
    Me[:, p1] = -Sinv
    Me[:, p2] = Sinv
    return dict(Az=Az, Bz=Bz, Md=Md, MdA=Md @ Az, MdB=Md @ Bz, Me=Me, R=d["R"])


def readout(ext: dict) -> np.ndarray:
    """Mo with Mo [z(t+h); w0; w1] = [dl; d(dl)/dt; Me z + R Y] at t + h: every linear
    read-out of a continuous-form update, fused with the exact step into one product."""
    Md, Me = ext["Md"], ext["Me"]
    n1, N = Md.shape
    W = ext["Bz"].shape[1]
    q = (W - n1) // 2
    Mo = np.zeros((3 * n1, N + W))
    Mo[:n1, :N] = Md
    Mo[n1:2 * n1, :N] = ext["MdA"]
    Mo[n1:2 * n1, N:] = ext["MdB"]
    Mo[2 * n1:, :N] = Me
    Mo[2 * n1:, N + n1 + q:] = ext["R"]
    return Mo


def predictor(A2: np.ndarray, k: float, ext: dict, after: bool) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the sampled form's linear part, Z = [z, omega], v = [F1(omega, u),
    F2(omega, u), dl(t - tau)] (eq. 39): omega' = A2 xi_e - k omega + F2 with
    xi_e = Me z + R omega + dl after t0 + tau, xi_e = xh1 before (no delayed data yet)."""
    Az, Bz = ext["Az"], ext["Bz"]
    N = Az.shape[0]
    n1, q = ext["Md"].shape[0], A2.shape[0]
    Iq = np.eye(q)
    A = np.zeros((N + q, N + q))
    A[:N, :N] = Az
    A[:N, N:] = Bz[:, n1 + q:]                       # Y -> omega in the extension
    if after:
        A[N:, :N] = A2 @ ext["Me"]
        A[N:, N:] = A2 @ ext["R"] - k * Iq
    else:
        A[N:, :n1] = A2
        A[N:, N:] = -k * Iq
    B = np.zeros((N + q, 2 * n1 + q))
    B[:N, :n1 + q] = Bz[:, :n1 + q]
    B[N:, n1:n1 + q] = Iq
    if after:
        B[N:, n1 + q:] = A2
    return A, B
