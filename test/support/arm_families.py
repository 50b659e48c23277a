"""Build the arm's external-torque families (external_torque, momentum_observer) and feed
them samples, for the tests: through the runner's own reading of the parameters
(runner/settings.py ``split``), so a test builds exactly what the node and the replay
build; streams of an arm's JointState in the intake's layout."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fto_ros.runner.runner import Runner
from fto_ros.runner.settings import split

ROOT = Path(__file__).resolve().parents[2]
PANDA = ROOT / "urdf" / "panda_gripper.urdf"
ARM7 = ROOT / "urdf" / "arm7.urdf"
PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
ARM7_JOINTS = [f"joint_a{i}" for i in range(1, 8)]


def flat(family: str, urdf=None, text=None, joints=(), **params) -> dict:
    """The flat parameters of ``family`` on a URDF file or text; ``params`` with '__' for
    '.' (external_torque__window=0.03)."""
    out = {"observer.type": family, "joints": list(joints)}
    if urdf is not None:
        out["plant.urdf"] = str(urdf)
    if text is not None:
        out["robot_description"] = text
    out.update({k.replace("__", "."): v for k, v in params.items()})
    return out


def observer(family: str, urdf=None, text=None, joints=(), **params):
    """The family's adapter, built as the runner builds it."""
    settings, cls, cfg = split(flat(family, urdf, text, joints, **params))
    return cls(cfg)


def runner(family: str, urdf=None, text=None, joints=(), **params) -> Runner:
    return Runner(flat(family, urdf, text, joints, **params))


def samples(run, obs, columns=None):
    """(y (N, n), u (N, n + k)) of an ArmRun (fto_ros/models/arm.py) for ``obs``: the
    measured positions and the efforts of its joints, the passive joints' positions."""
    names = list(run.names)
    ci = [names.index(j) for j in obs.joints]
    pi = [names.index(j) for j in obs.passive_joints]
    effort = run.effort if hasattr(run, "effort") and run.effort is not None else run.tau
    y = run.q_measured[:, ci]
    u = np.hstack([effort[:, ci], run.q_measured[:, pi]])
    return y, u


def contact_flags(obs) -> np.ndarray:
    """The observer's contact flags at its last sample (extras, arm/detect.py)."""
    from fto_ros.arm import detect as DT
    o = obs._ic[obs._K.EXTRA] + DT.X_HEAD
    return obs._st[o:o + obs.n_joints].copy()


def feed(obs, t, y, u):
    """Drive an adapter over a stream: (tau_ext (N, n), NaN where none; velocity (N, n);
    the samples at which a joint's contact flag rose)."""
    from fto_ros.arm import detect as DT
    N, n = len(t), obs.n_joints
    E, V = np.full((N, n), np.nan), np.zeros((N, n))
    onsets = []
    before = np.zeros(n)
    valid_at = obs._ic[obs._K.EXTRA] + DT.X_VALID
    for k in range(N):
        obs.update(float(t[k]), y[k], u[k])
        if obs._st[valid_at] > 0:
            E[k] = obs.unknown_input
        V[k] = obs.estimate[n:]
        flags = contact_flags(obs)
        if np.any((flags > 0.5) & (before < 0.5)):
            onsets.append(k)
        before = flags
    return E, V, onsets


def feed_runner(r, t, y, u):
    """The same through a Runner (its timeline: gaps, restarts): (tau_ext (N, n), NaN where
    none; the samples at which a contact flag rose; the runner's results)."""
    from fto_ros.arm import detect as DT
    obs = r.observer
    n = obs.n_joints
    base = list(r.convergence_fields).index("tau_ext_valid")
    E = np.full((len(t), n), np.nan)
    onsets, results = [], []
    before = np.zeros(n)
    for k in range(len(t)):
        r.set_input(float(t[k]), u[k])
        out = r.process(float(t[k]), y[k])
        results.append(out)
        if isinstance(out, str):
            continue
        c = out.convergence
        if c[base + DT.X_VALID] > 0.5:
            E[k] = out.unknown_input
        flags = c[base + DT.X_HEAD:base + DT.X_HEAD + n]
        if np.any((flags > 0.5) & (before < 0.5)):
            onsets.append(k)
        before = flags
    return E, onsets, results


def kernel_average(t, truth, T_of, edges=(), at=None):
    """The window's kernel average of a truth held between its samples t: at each
    evaluation instant ``at[k]`` (default: t), the sum over the pieces in [at_k - T_k, at_k]
    of their value times K(b / T_k) - K(a / T_k) (T_k = T_of(k), the window's span there;
    NaN where it is None).  A piece holds the value of its first sample, or of its last
    after one of the ``edges`` (where the truth jumps between two samples: a contact's
    start and end).  The window's ends are truth samples (the estimator's samples are)."""
    def K(s):
        s = np.clip(s, 0.0, 1.0)
        return s ** 3 * (10 - 15 * s + 6 * s * s)
    at = t if at is None else at
    out = np.full((len(at), truth.shape[1]), np.nan)
    for k, te in enumerate(at):
        T = T_of(k)
        if T is None:
            continue
        j = int(np.searchsorted(t, te - T - 1e-9))
        end = int(np.searchsorted(t, te - 1e-9))
        acc = np.zeros(truth.shape[1])
        for i in range(j, end):                       # truth_i held over [t_i, t_i+1)
            cut = [e for e in edges if t[i] < e < t[i + 1]]
            if cut:
                e = cut[0]
                acc += truth[i] * (K((te - t[i]) / T) - K((te - e) / T))
                acc += truth[i + 1] * (K((te - e) / T) - K((te - t[i + 1]) / T))
            else:
                acc += truth[i] * (K((te - t[i]) / T) - K((te - t[i + 1]) / T))
        out[k] = acc
    return out
