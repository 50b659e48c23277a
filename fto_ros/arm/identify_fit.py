"""The least-squares fit of the identification (ROS-free): weighted per joint, its standard
errors from the residual with the effective number of independent windows, the refusal of
what the data cannot see, and the windows a contact spoils.

The equations are one per window and joint: ``r0 = X delta`` (r0 the current model's
residual, delta the corrections of the unknowns). Each joint's rows are weighted by the
inverse of its residual level (the larger of the fitted residual's RMS and the encoder
noise's share), the columns normalised, and the system solved by least squares. The
windows overlap (one every few samples, T long), so neighbouring residuals are correlated:
the covariance of delta is the sandwich ``B^-1 S B^-1`` (B = X' W X), S the long-run
covariance of the windows' scores g_w = X_w' W r_w (Newey and West: their auto-covariances
up to ``lags`` windows, Bartlett's taper), from the residual itself. Its ratio to the
independent-window covariance ``sigma^2 B^-1`` (the median over the unknowns) is the
inflation; the windows over it, the effective number of independent windows. A bias the
residual does not show (a model form the data does not follow) is not in it.

Contacts first: after a robust fit (least median of squares over random sets of stretches,
then iteratively reweighted with Huber's weights, so that a contact's windows cannot pull
the fit that judges them), windows whose residual exceeds
``outlier`` robust standard deviations (1.4826 x the median absolute residual) on some joint
are taken as contacts and left out, until none is left; more than ``max_outliers`` of the
windows so spoilt is no contact-free stretch. Then refusal: an unknown whose standard error
exceeds ``ratio`` times its size (the larger of its fitted and its prior magnitude) is left at
its prior value, and the fit is repeated without it, the worst first, until every remaining
one is seen.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import FtoRosError


class FitRefused(FtoRosError, ValueError):
    """A stretch the fit cannot use (contacts everywhere, fewer windows than unknowns, no
    unknown the data can see)."""


@dataclass
class LeastSquares:
    """The outcome of :func:`solve` (p unknowns, nw windows, n joints)."""
    delta: np.ndarray                  # (p,) the corrections (0 where refused)
    se: np.ndarray                     # (p,) standard errors (nan where refused)
    active: np.ndarray                 # (p,) bool: fitted
    refused: list = field(default_factory=list)   # (index, se, size) in the order refused
    residual: np.ndarray | None = None # (nw, n) after the fit
    used: np.ndarray | None = None     # (nw,) bool: windows used (False: a contact)
    cond: float = math.nan             # of the weighted, normalised columns fitted
    inflation: float = 1.0
    effective_windows: float = math.nan
    scale: np.ndarray | None = None    # (n,) the joints' residual levels (the weights' inverse)


def _robust_sigma(r: np.ndarray) -> np.ndarray:
    return 1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0)


def long_run_covariance(G: np.ndarray, lags: int) -> np.ndarray:
    """sum over |l| <= L of (1 - |l| / (L + 1)) sum_t g_t g_(t+l)' of the rows g_t of ``G``
    (Newey and West's estimator with Bartlett's taper, L = ``lags``)."""
    S = G.T @ G
    for k in range(1, min(lags, G.shape[0] - 1) + 1):
        C = G[:-k].T @ G[k:]
        S += (1.0 - k / (lags + 1.0)) * (C + C.T)
    return S


def _lstsq(X, r, w, active, rows=None):
    """(delta, normalised weighted columns, their norms, weighted residual) on ``active``,
    joints weighted by ``w``, windows by ``rows`` (default 1)."""
    ww = w[None, :] if rows is None else w[None, :] * rows[:, None]
    Xa = X[:, :, active] * ww[:, :, None]
    A = Xa.reshape(-1, Xa.shape[2])
    norms = np.linalg.norm(A, axis=0)
    norms[norms == 0] = 1.0
    As = A / norms
    b = (r * ww).ravel()
    sol = np.linalg.lstsq(As, b, rcond=None)[0]
    delta = np.zeros(X.shape[2])
    delta[active] = sol / norms
    return delta, As, norms, b - As @ sol


def _robust_start(X, r0, floor, active, used, blocks: int = 20, pick: int = 4,
                  draws: int = 60):
    """A fit that contacts in up to about half of the windows do not spoil: fits on ``draws``
    random sets of ``pick`` of ``blocks`` stretches of consecutive windows, the one whose
    residual has the smallest product over the joints of the median absolute deviations
    (least median of squares, seeded: the same data give the same fit)."""
    rng = np.random.default_rng(0)
    idx = np.flatnonzero(used)
    parts = np.array_split(idx, min(blocks, max(idx.size // 4, 1)))
    n, need = r0.shape[1], 3 * int(active.sum())
    best, best_score = None, np.inf
    for _ in range(draws):
        rows = np.concatenate([parts[i] for i in rng.choice(len(parts),
                                                             min(pick, len(parts)),
                                                             replace=False)])
        if rows.size * n < need:
            continue
        sigma = np.maximum(_robust_sigma(r0[rows]), floor)
        delta = _lstsq(X[rows], r0[rows], 1.0 / sigma, active)[0]
        score = float(np.sum(np.log(np.maximum(_robust_sigma(r0[used] - X[used] @ delta),
                                               floor))))
        if score < best_score:
            best, best_score = delta, score
    return best


def _contacts(X, r0, floor, active, used, rounds: int = 10):
    """Per window, its largest residual in robust standard deviations after a robust fit
    (:func:`_robust_start`, then iteratively reweighted least squares with Huber's weights
    at 3 deviations): a contact's windows cannot pull the fit that judges them."""
    delta = _robust_start(X, r0, floor, active, used)
    if delta is None:
        delta = _lstsq(X[used], r0[used], 1.0 / np.maximum(_robust_sigma(r0[used]), floor),
                       active)[0]
    for k in range(rounds + 1):
        res = r0 - X @ delta
        sigma = np.maximum(_robust_sigma(res[used]), floor)
        z = np.max(np.abs(res - np.median(res[used], axis=0)) / sigma, axis=1)
        if k == rounds:
            return z
        rows = np.minimum(1.0, 3.0 / np.maximum(z, 1e-300))
        delta = _lstsq(X[used], r0[used], 1.0 / sigma, active, rows[used])[0]


def solve(X: np.ndarray, r0: np.ndarray, prior: np.ndarray, noise: np.ndarray, lags: int,
          ratio: float = 0.5, outlier: float = 30.0, max_outliers: float = 0.25,
          fixed: np.ndarray | None = None) -> LeastSquares:
    """Fit ``r0`` (nw x n) = ``X`` (nw x n x p) delta (module doc). ``prior`` (p): the
    unknowns' prior values (their sizes for the refusal); ``noise`` (n): each joint's residual
    level the encoder noise alone gives (a floor for the weights); ``lags``: over how many
    windows two windows overlap; ``fixed``: unknowns not fitted (left at their prior)."""
    nw, n, p = X.shape
    active = np.ones(p, dtype=bool) if fixed is None else ~np.asarray(fixed, dtype=bool)
    used = np.ones(nw, dtype=bool)
    if not active.any():
        raise FitRefused("nothing to fit: every unknown is fixed")
    floor = np.maximum(np.asarray(noise, dtype=float), 1e-12)
    refused = []
    for _ in range(10 if outlier > 0 else 0):       # contacts: left out before the fit
        spoilt = used & (_contacts(X, r0, floor, active, used) > outlier)
        if not spoilt.any():
            break
        used &= ~spoilt
        if used.mean() < 1 - max_outliers:
            raise FitRefused(f"no contact-free stretch: {100 * (1 - used.mean()):.0f} % of "
                             f"the windows show an external torque (residual above "
                             f"{outlier:g} robust standard deviations)")
    for _ in range(p + 1):                           # refusals, the worst first
        if used.sum() * n < 2 * active.sum():
            raise FitRefused(f"{used.sum()} windows of {n} joints cannot fit {active.sum()} "
                             f"unknowns: a longer stretch")
        scale = np.maximum(np.sqrt(np.mean(r0[used] ** 2, axis=0)), floor)
        for _pass in range(2):
            delta, As, norms, rw = _lstsq(X[used], r0[used], 1.0 / scale, active)
            res = r0 - X @ delta
            scale = np.maximum(np.sqrt(np.mean(res[used] ** 2, axis=0)), floor)
        dof = max(rw.size - active.sum(), 1)
        Binv = np.linalg.pinv(As.T @ As)
        G = (As * rw[:, None]).reshape(-1, n, As.shape[1]).sum(axis=1)   # per window
        cov_s = Binv @ long_run_covariance(G, lags) @ Binv * (rw.size / dof)
        iid = np.diag(Binv) * (rw @ rw / dof)
        infl = float(np.median(np.diag(cov_s) / np.maximum(iid, 1e-300)))
        se = np.full(p, np.nan)
        se[active] = np.sqrt(np.maximum(np.diag(cov_s), 0.0)) / norms
        size = np.maximum(np.abs(prior + delta), np.abs(prior))
        bad = np.where(active, se / np.maximum(size, 1e-300), -np.inf)
        worst = int(np.argmax(bad))
        if bad[worst] > ratio:
            active[worst] = False
            refused.append((worst, float(se[worst]), float(size[worst])))
            if not active.any():
                raise FitRefused("the stretch sees none of the unknowns (every standard error "
                                 f"above {ratio:g} of its value): more motion, a longer stretch")
            continue
        s = np.linalg.svd(As, compute_uv=False)
        return LeastSquares(delta=delta, se=se, active=active, refused=refused, residual=res,
                            used=used, cond=float(s[0] / s[-1]) if s[-1] > 0 else math.inf,
                            inflation=infl, effective_windows=float(used.sum() / infl),
                            scale=scale)
    raise FitRefused("the fit did not settle")
