"""Small linear-systems checks shared by the observers (ROS-free)."""
from __future__ import annotations

import warnings

import numpy as np

from .errors import ConfigError


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


def place_observer_poles(A: np.ndarray, C: np.ndarray, poles, parameter: str) -> np.ndarray:
    """Gain L (n x p) placing the eigenvalues of A - L C at ``poles`` (negative reals), or
    ConfigError naming ``parameter``."""
    from scipy.signal import place_poles        # scipy.signal is slow to import: only here
    n, p = A.shape[0], C.shape[0]
    poles = np.asarray(poles, dtype=float)
    if poles.size != n:
        raise ConfigError(parameter, f"expected {n} poles, got {poles.size}")
    if np.any(poles >= 0):
        raise ConfigError(parameter, f"all poles must be negative, got {poles.tolist()}")
    if p == 1 and len(set(poles.tolist())) < n:
        raise ConfigError(parameter, "with one output the poles must be distinct")
    try:
        with warnings.catch_warnings():
            # scipy warns when its robustness iteration (not the placement) stops early, e.g.
            # "Convergence was not reached" at 14 states; the placed poles are checked below
            warnings.simplefilter("ignore")
            L = place_poles(A.T, C.T, poles).gain_matrix.T
    except ValueError as exc:
        raise ConfigError(parameter, f"cannot place {poles.tolist()} ({exc}); when (A, C) is "
                          "not observable give the gain L directly") from None
    got = np.linalg.eigvals(A - L @ C) if np.all(np.isfinite(L)) else np.full(n, np.nan)
    err = placement_error(got, poles)
    if not err <= POLE_TOLERANCE:
        raise ConfigError(parameter, f"the poles were not placed (eigenvalues of A - L C: "
                          f"{np.sort_complex(got).tolist()}, relative error {err:.2g}); choose "
                          "other poles or give the gain L directly")
    return L


#: largest relative error of a placed pole (|placed - asked| / max |asked|) accepted: a
#: repeated pole of multiplicity k is only computable to ~eps^(1/k) (1.2e-4 for k = 4), and
#: a pole 0.1 % off is still the design asked for
POLE_TOLERANCE = 1e-3


def placement_error(got: np.ndarray, asked: np.ndarray) -> float:
    """max |got - asked| / max |asked|, the eigenvalues matched in sorted order (the asked
    poles are real: the placed ones are sorted by real part, then imaginary)."""
    a = np.sort(np.asarray(asked, dtype=float))
    g = np.sort_complex(np.asarray(got, dtype=complex))
    return float(np.max(np.abs(g - a)) / max(np.max(np.abs(a)), 1e-300))
