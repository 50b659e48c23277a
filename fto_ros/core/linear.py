"""Small linear-systems checks shared by the observers (ROS-free)."""
from __future__ import annotations

import numpy as np


def observability_matrix(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """[C; C A; ...; C A^(n-1)]."""
    n = A.shape[0]
    blocks = [C]
    for _ in range(n - 1):
        blocks.append(blocks[-1] @ A)
    return np.vstack(blocks)


def observability_rank(A: np.ndarray, C: np.ndarray) -> int:
    """Numerical rank of the pair (A, C), by the PBH test at every eigenvalue of A.

    The PBH test is better conditioned than the rank of the observability
    matrix, whose powers of A overflow scale for stiff plants (the DC motor's
    a4 = 200 makes C A^2 four orders larger than C).
    """
    n = A.shape[0]
    worst = n
    for lam in np.linalg.eigvals(A):
        pbh = np.vstack([A - lam * np.eye(n), C])
        s = np.linalg.svd(pbh, compute_uv=False)
        tol = max(pbh.shape) * np.finfo(float).eps * max(s[0], 1.0) * 1e3
        worst = min(worst, int(np.sum(s > tol)))
    return worst
