"""Structure of ``x' = A x + D zeta, y = C x`` with respect to an unknown input (ROS-free).

Fridman, Levant & Davila 2007, Sections 2 and 5:

- (vector) relative degree (r_1, ..., r_p) of y w.r.t. zeta (eq. 3, 42-43): c_i A^s D = 0
  for s < r_i - 1 and the decoupling matrix Q = [c_i A^(r_i - 1) D] invertible;
- invariant zeros: the s where the Rosenbrock matrix R(s) = [[sI - A, -D], [C, 0]] (eq. 2)
  loses rank; computed as the finite generalized eigenvalues of the pencil
  ([[A, D], [-C, 0]], diag(I, 0));
- strong observability <=> no invariant zeros <=> total relative degree r = n (Thm 2.1);
  strong detectability <=> relative degree exists and every zero has Re < 0 (Thm 2.2);
- the coordinates theta = T e of eq. (33)-(34) / (46)-(50) for the error system
  (A_t = A - L C, D, C): T1 stacks c_i A_t^j, j < r_i (the canonical observation
  coordinates of the error), T2 spans a complement with T2 D = 0, so that

      theta1' = A11 theta1 + A12 theta2 + [0 .. Q zeta ..]
      theta2' = A21 theta1 + A22 theta2            (zero dynamics: eig(A22) = the zeros)

Every check raises :class:`StructureError` with a message a user can act on.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .errors import StructureError
from .linear import observability_matrix

#: relative tolerance for "c A^s D = 0" and for rank decisions
RTOL = 1e-9


def relative_degree(A: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[list[int], np.ndarray]:
    """Vector relative degree (r_i per output) and the decoupling matrix Q (eq. 42-43).

    Raises StructureError('relative_degree') when an output never sees zeta
    (c_i A^s D = 0 for all s < n: D lies in that output's unobservable subspace),
    or when Q is singular (the vector relative degree does not exist).
    """
    n = A.shape[0]
    p, q = C.shape[0], D.shape[1]
    dnorm = max(np.linalg.norm(D), 1e-300)
    r: list[int] = []
    rows = []
    for i in range(p):
        c = C[i:i + 1]
        for s in range(n):
            cd = c @ D
            if np.linalg.norm(cd) > RTOL * max(np.linalg.norm(c), 1e-300) * dnorm:
                r.append(s + 1)
                rows.append(cd.ravel())
                break
            c = c @ A
        else:
            raise StructureError(
                "relative_degree",
                f"output {i} has no relative degree w.r.t. the unknown input: c_{i} A^s D = 0 for "
                f"s = 0..{n - 1} (D lies in the unobservable subspace of that output, so the unknown "
                f"input can never be seen in it; the plant is not strongly detectable)")
    if p != q:
        raise StructureError(
            "relative_degree",
            f"the vector relative degree needs as many unknown inputs as outputs (Section 5); "
            f"got {q} unknown input(s) and {p} output(s)")
    Q = np.array(rows)
    sv = np.linalg.svd(Q, compute_uv=False)
    if sv[-1] <= RTOL * max(sv[0], 1e-300) * 1e3:
        raise StructureError(
            "relative_degree",
            f"the vector relative degree does not exist: the decoupling matrix Q = "
            f"[c_i A^(r_i-1) D] (r = {tuple(r)}) is singular (singular values "
            f"{', '.join(f'{v:.3g}' for v in sv)})")
    return r, Q


def invariant_zeros(A: np.ndarray, C: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Invariant zeros of (A, D, C): finite s where the Rosenbrock matrix (2) drops rank.

    Square case (as many outputs as unknown inputs): finite generalized
    eigenvalues of ([[A, D], [-C, 0]], diag(I, 0)), via QZ.
    """
    n, q = A.shape[0], D.shape[1]
    p = C.shape[0]
    M = np.block([[A, D], [-C, np.zeros((p, q))]])
    E = np.zeros_like(M)
    E[:n, :n] = np.eye(n)
    ab = sla.eig(M, E, right=False, homogeneous_eigvals=True)
    alpha, beta = ab[0], ab[1]
    scale = max(np.linalg.norm(M, 2), 1.0)
    finite = np.abs(beta) * scale * 1e8 > np.abs(alpha)
    finite &= np.abs(beta) > 1e-10
    z = alpha[finite] / beta[finite]
    return np.sort_complex(z)


@dataclass
class Structure:
    """Result of :func:`analyse` for the error system (A - L C, D, C)."""

    r: list[int]              #: relative degree per output
    r_total: int              #: sum of r
    Q: np.ndarray             #: decoupling matrix c_i A^(r_i - 1) D (p x q)
    zeros: np.ndarray         #: invariant zeros (Rosenbrock pencil)
    zeros_a22: np.ndarray     #: eig(A22), the zero dynamics (should equal zeros)
    n_observable: int         #: rank of the observability matrix (n_O)
    strongly_observable: bool
    T: np.ndarray             #: n x n, theta = T e
    Tinv: np.ndarray
    A_theta: np.ndarray       #: T (A - L C) T^-1
    G: np.ndarray             #: p x n: rows c_i A_t^(r_i) T^-1 (y_i^(r_i) = G_i theta + Q_i zeta)
    blocks: list[slice]       #: rows of theta1 belonging to each output

    @property
    def A21(self) -> np.ndarray:
        return self.A_theta[self.r_total:, :self.r_total]

    @property
    def A22(self) -> np.ndarray:
        return self.A_theta[self.r_total:, self.r_total:]


def _rank_tol(s: np.ndarray, shape) -> float:
    return max(shape) * np.finfo(float).eps * max(s[0] if s.size else 0.0, 1.0) * 1e3


def analyse(A: np.ndarray, C: np.ndarray, D: np.ndarray, L: np.ndarray) -> Structure:
    """Relative degree, zeros, strong observability/detectability and the coordinates T.

    Raises StructureError with condition 'relative_degree', 'not_strongly_detectable'
    (an invariant zero with Re >= 0) or 'luenberger' (A - L C not Hurwitz).
    """
    n = A.shape[0]
    r, Q = relative_degree(A, C, D)
    rt = sum(r)
    zeros = invariant_zeros(A, C, D)
    _check_zeros(zeros)
    At = A - L @ C
    eig_t = np.linalg.eigvals(At)
    if np.max(eig_t.real) >= 0:
        raise StructureError("luenberger", f"A - L C is not Hurwitz (eigenvalues "
                             f"{', '.join(f'{z:.4g}' for z in eig_t)}): choose L (or the poles) so "
                             f"that every eigenvalue has a negative real part")
    # T1: c_i At^j, j < r_i, output by output
    rows, blocks = [], []
    for i in range(C.shape[0]):
        c = C[i:i + 1]
        start = len(rows)
        for _ in range(r[i]):
            rows.append(c.ravel().copy())
            c = c @ At
        blocks.append(slice(start, len(rows)))
    T1 = np.array(rows)
    s1 = np.linalg.svd(T1, compute_uv=False)
    if s1[-1] <= _rank_tol(s1, T1.shape) * 1e3:
        raise StructureError("relative_degree", "the rows c_i A^j (j < r_i) are numerically "
                             "dependent (Lemma 5.1 fails): the vector relative degree is ill-conditioned")
    if rt < n:
        # T2: complement of the 'D-annihilating' rows of T1 inside the left null space of D
        N = sla.null_space(D.T).T                        # (n - q) x n, orthonormal rows, N D = 0
        last = {b.stop - 1 for b in blocks}
        T1a = np.array([rows[k] for k in range(rt) if k not in last]).reshape(-1, n)
        X = T1a @ N.T                                    # coordinates of T1a in the basis N
        Y = sla.null_space(X) if X.size else np.eye(N.shape[0])
        T2 = (N.T @ Y).T                                 # (n - r) x n
        T = np.vstack([T1, T2])
    else:
        T = T1
    sT = np.linalg.svd(T, compute_uv=False)
    if sT[-1] <= _rank_tol(sT, T.shape):
        raise StructureError("relative_degree", "cannot complete the canonical coordinates: T is "
                             "singular")
    Tinv = np.linalg.inv(T)
    A_theta = T @ At @ Tinv
    Gi = []
    for i in range(C.shape[0]):
        Gi.append((C[i:i + 1] @ np.linalg.matrix_power(At, r[i]) @ Tinv).ravel())
    G = np.array(Gi)
    zeros_a22 = np.sort_complex(np.linalg.eigvals(A_theta[rt:, rt:])) if rt < n else np.zeros(0)
    n_obs = observability_index(A, C)
    st = Structure(r=r, r_total=rt, Q=Q, zeros=zeros, zeros_a22=zeros_a22, n_observable=n_obs,
                   strongly_observable=rt == n, T=T, Tinv=Tinv, A_theta=A_theta, G=G,
                   blocks=blocks)
    _check_zeros(zeros_a22)
    return st


def _check_zeros(zeros: np.ndarray) -> None:
    bad = [z for z in zeros if z.real >= 0]
    if bad:
        raise StructureError(
            "not_strongly_detectable",
            f"the plant is not strongly detectable: invariant zero(s) "
            f"{', '.join(f'{z:.4g}' for z in bad)} (Rosenbrock matrix) have Re >= 0, so the "
            f"zero dynamics is not asymptotically stable (not minimum phase; Theorem 2.2)")


def observability_index(A: np.ndarray, C: np.ndarray) -> int:
    """Rank of the observability matrix P (n_O of the paper), by SVD."""
    P = observability_matrix(A, C)
    s = np.linalg.svd(P, compute_uv=False)
    return int(np.sum(s > _rank_tol(s, P.shape)))
