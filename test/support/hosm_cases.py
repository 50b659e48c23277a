"""hosm's test cases (test/unit/observers/test_hosm*.py): an observer from its parameters,
the exact trajectories of the paper's examples (plant + sinusoidal exosystem stepped with
expm: machine precision, no integrator tolerance), a run over samples, and the paper's two
examples as observers."""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from fto_ros.core.params import resolve
from fto_ros.models import fld_examples as fx
from fto_ros.observers.hosm import HosmObserver

def make(**cfg) -> HosmObserver:
    return HosmObserver(resolve(HosmObserver.PARAMS, cfg, "hosm."))


def exo_traj(A, D, x0, t, freqs, coef, const):
    """x(t), zeta(t) for x' = A x + D zeta, zeta_j = const_j + sum_f c_jf,cos cos(f t) + c_jf,sin sin(f t).

    coef[j] = list of (f, c_cos, c_sin).  Exact by expm of the plant + exosystem (variable t ok).
    """
    n, q = A.shape[0], D.shape[1]
    nw = 2 * len(freqs) + 1
    S = np.zeros((nw, nw))
    for i, f in enumerate(freqs):
        S[2 * i, 2 * i + 1] = -f      # w = (cos f t, sin f t)
        S[2 * i + 1, 2 * i] = f
    E = np.zeros((q, nw))
    for j in range(q):
        E[j, -1] = const[j]
        for f, cc, cs in coef[j]:
            i = freqs.index(f)
            E[j, 2 * i] += cc
            E[j, 2 * i + 1] += cs
    Aa = np.zeros((n + nw, n + nw))
    Aa[:n, :n], Aa[:n, n:], Aa[n:, n:] = A, D @ E, S
    w0 = np.zeros(nw)
    w0[0::2][:len(freqs)] = 1.0
    w0[-1] = 1.0
    xa = np.concatenate([x0, w0])
    X, Z = np.empty((len(t), n)), np.empty((len(t), q))
    cache = {}
    for k in range(len(t)):
        if k:
            h = round((t[k] - t[k - 1]) * 1e9)
            if h not in cache:
                cache[h] = expm(Aa * h * 1e-9)
            xa = cache[h] @ xa
        X[k], Z[k] = xa[:n], E @ xa[n:]
    return X, Z


def fld_traj(example: int, t):
    """The paper's plants driven by zeta = cos 0.5t + 0.5 sin t + 0.5."""
    A, D, x0 = ((fx.EXAMPLE1_A, fx.EXAMPLE1_D, fx.EXAMPLE1_X0) if example == 1
                else (fx.EXAMPLE2_A, fx.EXAMPLE2_D, fx.EXAMPLE2_X0))
    return exo_traj(A, D[:, None], np.array(x0), t, [0.5, 1.0], [[(0.5, 1.0, 0.0), (1.0, 0.0, 0.5)]],
                    [0.5])


def run(obs, t, Y, U=None):
    X = np.empty((len(t), obs.n_states))
    Z = np.full((len(t), obs.n_outputs), np.nan)
    obs.reset(t[0])
    for k in range(len(t)):
        obs.update(t[k], Y[k], np.zeros(obs.n_inputs) if U is None else U[k])
        X[k] = obs.estimate
        if obs.unknown_input is not None:
            Z[k] = obs.unknown_input
    return X, Z


def ex1(**kw):
    cfg = dict(n_states=4, A=fx.EXAMPLE1_A.ravel().tolist(), C=[1.0, 0, 0, 0],
               D=fx.EXAMPLE1_D.tolist(), L=[5.0, 5, 5, 5], M=[1.0], smoothness_order=1)
    cfg.update(kw)
    return make(**cfg)


def ex2(**kw):
    cfg = dict(n_states=6, A=fx.EXAMPLE2_A.ravel().tolist(), C=[1.0, 0, 0, 0, 0, 0],
               D=fx.EXAMPLE2_D.tolist(), L=fx.EXAMPLE2_L.tolist(), M=[2.0], smoothness_order=0)
    cfg.update(kw)
    return make(**cfg)
