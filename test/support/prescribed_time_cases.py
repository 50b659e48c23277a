"""prescribed_time's test cases (test/unit/observers/test_prescribed_time*.py,
test/system/test_prescribed_time_live.py): the example configs, Example 1's initial
conditions and values of m, an observer from a canonical plant, the plant's exact ZOH
samples, a run of the observer over them, and the paper's continuous-time error and
injection bound (Lemma 1, Theorem 1)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.linalg import expm

from fto_ros.core.params import resolve
from fto_ros.models.canonical_form import DOUBLE_INTEGRATOR, CanonicalPlant
from fto_ros.observers.prescribed_time import PrescribedTimeObserver

ROOT = Path(__file__).resolve().parents[2]
DI_CONFIG = ROOT / "config" / "double_integrator_prescribed_time.yaml"
TO_CONFIG = ROOT / "config" / "third_order_prescribed_time.yaml"
EPS_TRACK = 1e-3
#: Example 1's initial conditions (Fig. 1: (0, 1), (0, 5), (0, 10); Figs. 4-6: (20, 1))
EXAMPLE1_X0 = [(0.0, 1.0), (0.0, 5.0), (0.0, 10.0), (20.0, 1.0)]
#: the values of m tried (the text of Figs. 4-6 says "three values of m" without listing them)
EXAMPLE1_M = [1, 2, 3, 4, 5, 10]


def make(plant: CanonicalPlant = DOUBLE_INTEGRATOR, **over) -> PrescribedTimeObserver:
    vals = dict(n_states=plant.n, relative_degree=plant.r, n_inputs=1, a=list(plant.a),
                b=list(plant.b), T=5.0, m=1, l=[1.0] * plant.n if plant.n == 2 else
                list(np.poly(-np.ones(plant.n))[1:]))
    vals.update(over)
    return PrescribedTimeObserver(resolve(PrescribedTimeObserver.PARAMS, vals, prefix="prescribed_time."))


def simulate_zoh(plant: CanonicalPlant, x0, t, u):
    """Exact samples of the plant with u held on [t_k, t_k+1) (what the bags' DAC does)."""
    A, B = plant.matrices()
    n = plant.n
    X = np.zeros((len(t), n))
    X[0] = x0
    cache = {}
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        key = round(h * 1e9)
        if key not in cache:
            M = np.zeros((n + 1, n + 1))
            M[:n, :n] = A * h
            M[:n, n] = B * h
            E = expm(M)
            cache[key] = (E[:n, :n], E[:n, n])
        Ad, Bd = cache[key]
        X[k + 1] = Ad @ X[k] + Bd * u[k]
    return X


def run(obs, plant, x0, t, u, x0_hat=None):
    """Feed the samples; returns (errors x - x_hat, injections gamma, largest gains)."""
    X = simulate_zoh(plant, x0, t, u)
    obs.reset(t[0], x0_hat)
    err, gam, gmax = [], [], []
    for k in range(len(t)):
        obs.update(t[k], X[k, :1], np.array([u[k]]))
        err.append(X[k] - obs.estimate)
        gam.append(obs.injections.copy())
        gmax.append(float(np.max(np.abs(obs.gains))))
    return np.array(err), np.array(gam), np.array(gmax)


def exact_errors(obs, e0, t, t0=0.0):
    """The paper's continuous-time error Phi(t, t0) e0 inside the first window (Lemma 1)."""
    return np.array([e0 if tk <= t0 else obs.transition_window(np.array(e0, float), 0.0, tk - t0)
                     for tk in t])


def injection_bound(obs, e0) -> np.ndarray:
    """Theorem 1 (eq. 40-41): |gamma_i| <= sum_k |h_bar_ik| * max_t |z~_1(t)|."""
    Lam = np.diag(np.ones(obs.n - 1), 1) if obs.n > 1 else np.zeros((1, 1))
    Lam[:, 0] = -obs.l
    z0 = obs.pbar @ np.asarray(e0, float)          # W(t0) = P*(mu_1 = 1) = p_bar
    ts = np.linspace(0.0, obs.T, 2001)
    z1 = max(abs((expm(Lam * s) @ z0)[0]) for s in ts)
    return np.abs(obs.Hg).sum(axis=1) * z1


def grid(T_end, h):
    return np.arange(int(round(T_end / h)) + 1) * h
