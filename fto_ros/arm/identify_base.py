"""The base parameters of an arm's inertias (ROS-free): which combinations of the bodies'
inertia parameters the joint torques can show at all.

Each body has 10 inertia parameters (m, m c, inertia about its origin: :data:`PARAMETERS`);
the torques of the listed joints depend on some only in fixed combinations (a body turning
about one fixed axis shows one moment of inertia; the mass of the last body shows only
through the first moments of the body before it, and so on), whatever the motion. The
numerical base set (Gautier's method): the columns of the torque regressor M a + C v + g per
parameter at random states, normalised, QR with column pivoting; the pivoted columns whose
diagonal exceeds ``tol`` of the largest are independent, every other is a fixed
combination of them, X_D = X_I K. Fitting the independent ones with the dependent ones
held at their URDF values identifies the base parameters theta_I + K theta_D exactly; the
bodies' parameters that come out are one representative of them (the dependent ones keep
their URDF values). Whether THE DATA excites each base parameter is a separate question:
the fit's standard errors (:mod:`.identify_fit`) answer it.
"""
from __future__ import annotations

import numpy as np
from scipy import linalg

from .identify_regressor import direct_terms
from .model import RigidBodyModel
from .tree import ACTIVE, TYPE

#: the 10 inertia parameters of a body (about its origin, its axes)
PARAMETERS = ("m", "mx", "my", "mz", "ixx", "iyy", "izz", "iyz", "ixz", "ixy")


def moving_bodies(model: RigidBodyModel) -> list[tuple[int, str]]:
    """(tree row, the link that is the body's frame) of every body a listed joint moves."""
    rows = model.tree.rows
    child = {j.name: j.child for j in model.robot.joints}
    return [(i, child[name]) for i, name in enumerate(model.tree.names) if rows[i, ACTIVE] >= 0]


def structural_base(model: RigidBodyModel, bodies: list[int], states: int = 120,
                    seed: int = 0, tol: float = 1e-8):
    """(independent, dependent, K) over the columns (body, parameter) of ``bodies`` in the
    order body-major, :data:`PARAMETERS` within: index lists and the matrix with
    X_dependent = X_independent K (module doc)."""
    rng = np.random.default_rng(seed)
    n = model.n
    prismatic = np.array([model.tree.rows[model.tree.row_of(j), TYPE] == 1.0
                          for j in model.joints])
    Q = np.where(prismatic, rng.uniform(-0.3, 0.3, (states, n)),
                 rng.uniform(-np.pi, np.pi, (states, n)))
    V, A = rng.standard_normal((states, n)), rng.standard_normal((states, n))
    P = np.tile(model.passive_default, (states, 1))
    nb = model.tree.rows.shape[0]
    cols = []
    for b in bodies:
        for k in range(10):
            inertia = np.zeros((nb, 10))
            inertia[b, k] = 1.0
            cols.append(direct_terms(model, inertia, Q, P, V, A).ravel())
    X = np.stack(cols, axis=1)
    norms = np.linalg.norm(X, axis=0)
    nonzero = norms > 1e-12 * max(norms.max(), 1e-300)
    Xs = X / np.where(nonzero, norms, 1.0)
    _, R, piv = linalg.qr(Xs, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > tol * d[0])) if d.size and d[0] > 0 else 0
    independent = sorted(int(i) for i in piv[:rank] if nonzero[i])
    dependent = [i for i in range(X.shape[1]) if i not in independent]
    K = np.linalg.lstsq(X[:, independent], X[:, dependent], rcond=None)[0] if dependent else \
        np.zeros((len(independent), 0))
    return independent, dependent, K
