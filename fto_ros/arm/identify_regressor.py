"""The columns of the identification (ROS-free): the window form of :mod:`.identify_windows`
per unknown parameter, from the arm's compiled dynamics.

M(q), Mdot, C^T v and g(q) are linear in the bodies' inertia parameters (m, m c, inertia
about the body's origin: 10 per body), so the column of a parameter is the window form of
the terms computed with a tree that holds only that parameter's inertia (every other body
empty, no armature): for a per-link scale, the link's own URDF inertia (the column is its
contribution at factor 1); for a body parameter, a unit value; for a payload parameter, a
unit value at the payload's frame, moved into its body (:func:`.tree.shift_params`). The
friction columns are b: integral k' q~ and f_c: integral k tanh(v / w), per joint.

Speed is secondary (offline): the terms of each column are computed at every sample (one
compiled pass over the samples per column).
"""
from __future__ import annotations

import numpy as np

from ..core.jit import jit
from . import dynamics as dyn
from .identify_windows import Windows, centred_velocity
from .model import RigidBodyModel
from .tree import ARMATURE, INERTIA, shift_params


@jit
def _sample_terms(rows, n, Q, P, V):
    """[M, Mdot, C^T v, g] (flat, :func:`.dynamics.momentum_terms`) at every sample."""
    N = Q.shape[0]
    out = np.empty((N, 2 * n * n + 2 * n))
    for k in range(N):
        out[k] = dyn.momentum_terms(rows, n, Q[k], P[k], V[k], True)
    return out


def direct_terms(model: RigidBodyModel, inertia: np.ndarray, Q, P, V, A) -> np.ndarray:
    """M a + C v + g (samples x n) of a tree holding only ``inertia`` (bodies x 10), no
    armature: a column of the plain (non-window) regressor, for the structural analysis of
    :mod:`.identify_base` and the slow references of the tests."""
    rows = _rows_with(model, inertia)
    n = model.n
    return np.array([dyn.inverse_dynamics(rows, n, Q[k], P[k], V[k], A[k], True)
                     for k in range(len(Q))])


def _rows_with(model: RigidBodyModel, inertia: np.ndarray) -> np.ndarray:
    rows = model.tree.rows.copy()
    rows[:, INERTIA:INERTIA + 10] = inertia
    rows[:, ARMATURE] = 0.0
    return rows


class WindowRegressor:
    """The window form of one contact-free stretch: the data ``y`` = integral k tau per window
    and joint, the current model's prediction, and the columns of the unknowns.

    Args: the model (its current parameters are the prior), the stamps ``t`` (s), positions
    ``q`` (samples x n), torques ``tau`` (the torque acting from each sample to the next),
    the passive joints' positions ``passive`` (samples x k, or None: their defaults), the
    window ``T``, one window every ``stride`` samples, no window over a step longer than
    ``max_gap``; ``mask``: samples usable (False: none of their windows is used)."""

    def __init__(self, model: RigidBodyModel, t, q, tau, passive=None, T: float = 0.1,
                 stride: int = 10, max_gap: float = 0.01, mask=None, velocity_half: int = 6):
        self.model = model
        self.t = np.ascontiguousarray(t, dtype=float)
        self.q = np.ascontiguousarray(q, dtype=float)
        N, n = self.q.shape
        self.n = n
        k = len(model.passive_joints)
        self.passive = (np.tile(model.passive_default, (N, 1)) if passive is None else
                        np.ascontiguousarray(passive, dtype=float)).reshape(N, k)
        self.windows = Windows(self.t, T, stride, max_gap, mask)
        self.v = np.ascontiguousarray(centred_velocity(self.t, self.q, velocity_half))
        self.tau = np.asarray(tau, dtype=float)
        #: integral k tau per window and joint (the torque held between samples)
        self.y = self.windows.Z @ self.tau
        self._terms_cache = None

    # -- model terms ------------------------------------------------------------------------
    def terms(self, rows: np.ndarray) -> np.ndarray:
        """[M, Mdot, C^T v, g] at every sample for the tree ``rows``."""
        return _sample_terms(rows, self.n, self.q, self.passive, self.v)

    def window_form(self, terms: np.ndarray) -> np.ndarray:
        """integral k'' M q~ - integral k' Mdot q~ - integral k (C^T v - g) per window."""
        n, N = self.n, self.q.shape[0]
        M = terms[:, :n * n].reshape(N, n, n)
        Md = terms[:, n * n:2 * n * n].reshape(N, n, n)
        phi = terms[:, 2 * n * n:2 * n * n + n] - terms[:, 2 * n * n + n:]
        return self.windows.momentum(M, Md, self.q) - self.windows.A0 @ phi

    def model_terms(self) -> np.ndarray:
        """The current model's terms at every sample (armature and payloads included)."""
        if self._terms_cache is None:
            self._terms_cache = self.terms(self.model.tree.rows)
        return self._terms_cache

    def prediction(self) -> np.ndarray:
        """The current model's integral k tau per window (friction not included)."""
        return self.window_form(self.model_terms())

    def gravity(self) -> np.ndarray:
        """g(q) of the current model at every sample."""
        n = self.n
        return self.model_terms()[:, 2 * n * n + n:]

    def noise_level(self, sigma_q) -> np.ndarray:
        """Per window and joint, the standard deviation white encoder noise of ``sigma_q``
        rad (per joint) gives the window's equation: sqrt(sum_k sigma_k^2 sum_j (a_j
        M_j,ik)^2), a_j the weights of k''."""
        n, N = self.n, self.q.shape[0]
        M2 = self.model_terms()[:, :n * n] ** 2
        S = (self.windows.A2.multiply(self.windows.A2) @ M2).reshape(-1, n, n)
        return np.sqrt(np.einsum("wik,k->wi", S, np.asarray(sigma_q, dtype=float) ** 2))

    # -- columns ----------------------------------------------------------------------------
    def inertia_column(self, inertia: np.ndarray) -> np.ndarray:
        """The window form of a tree holding only ``inertia`` (bodies x 10), no armature."""
        return self.window_form(self.terms(_rows_with(self.model, inertia)))

    def link_column(self, link: str) -> np.ndarray:
        """A link's own URDF inertia (its contribution to M, Mdot, C^T v and g)."""
        b, params = self.model.tree.link_params(link)
        inertia = np.zeros((self.model.tree.rows.shape[0], 10))
        inertia[b] = params
        return self.inertia_column(inertia)

    def body_column(self, body: int, index: int) -> np.ndarray:
        """Unit value of inertia parameter ``index`` (0..9) of body row ``body``."""
        inertia = np.zeros((self.model.tree.rows.shape[0], 10))
        inertia[body, index] = 1.0
        return self.inertia_column(inertia)

    def frame_column(self, frame: str, index: int) -> np.ndarray:
        """Unit value of inertia parameter ``index`` (about ``frame``'s origin, its axes)."""
        b, R, p = self.model.tree.frames[frame]
        inertia = np.zeros((self.model.tree.rows.shape[0], 10))
        unit = np.zeros(10)
        unit[index] = 1.0
        inertia[b] = shift_params(unit, R, p)
        return self.inertia_column(inertia)

    def viscous_column(self) -> np.ndarray:
        """integral k' q~ per window and joint (the column of b_i is joint i's)."""
        return self.windows.of_positions(self.q, self.windows.A1)

    def coulomb_column(self, width: float) -> np.ndarray:
        """integral k tanh(v / w) per window and joint."""
        return self.windows.of_smooth_sign(self.v, width)
