"""prescribed_time, global_norm, high_gain, luenberger: the compiled kernels and the numpy path
(FTO_ROS_NUMBA=0) give the same outputs, bit for bit, on the committed (bag, config) pairs
of the families (luenberger: each config with its first bag) and on runs that reach what
those configs do not:

- prescribed_time: the stop and constant modes (after the window, frozen gains), the
  sampling limit of a sixth-order plant in the restart and constant modes, a first-order
  hold of the input;
- global_norm: the reduced form with a linear hold; three states (e^(A h) from Cardano's
  roots, the spectral sum, the Taylor series) and four (numpy's roots);
- high_gain: the model term at the estimate with a linear hold; three states;

each with irregular stamps, a gap the runner restarts at (warm restarts within T and beyond
for prescribed_time), a reset and a restart from a given state.

Each side runs in a subprocess of its own (the compiled one with FTO_ROS_NUMBA=1, the other
with 0), so the test means the same whichever way pytest itself was started.  Measured
exactly equal: compiled powers are numpy's own loop and libm's pow (core/powers.py),
cached step matrices scipy's expm, products BLAS's, complex arithmetic CPython's.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]
FAMILIES = ("prescribed_time", "global_norm", "high_gain", "luenberger")
T_END = 9.0


def _pairs():
    import reference_runs as RR
    _, meta = RR.load_reference()
    pairs, seen = [], set()
    for p in meta["pairs"]:
        config = p["params"][-1]
        if any(f in config for f in FAMILIES) and not ("luenberger" in config and config in seen):
            pairs.append(p)
            seen.add(config)
    return pairs


def _flat(name: str, **over) -> dict:
    from fto_ros.runner import load_params_file
    flat = load_params_file(ROOT / "config" / f"{name}.yaml")
    typ = flat["observer.type"]
    flat.update({f"{typ}.{k}": v for k, v in over.items()})
    return flat


def _chain(n: int, **over) -> dict:
    flat = {"observer.type": "prescribed_time", "prescribed_time.n_states": n,
            "prescribed_time.relative_degree": n, "prescribed_time.a": [0.0] * n,
            "prescribed_time.b": [1.0], "prescribed_time.T": 2.0, "prescribed_time.m": 1,
            "prescribed_time.l": [float(c) for c in np.poly(-np.ones(n))[1:]]}
    flat.update({f"prescribed_time.{k}": v for k, v in over.items()})
    return flat


def _companion(typ: str, n: int, **over) -> dict:
    """global_norm / high_gain on an n-state chain x_{n-1}' = -(s + 1)^n's terms + 0.5 sin y."""
    coef = np.poly(-np.ones(n))[1:][::-1]
    f = " + ".join(f"{-c:g}*" + ("y" if i == 0 else f"x{i}") for i, c in enumerate(coef))
    flat = {"observer.type": typ, f"{typ}.n_states": n, f"{typ}.f": f + " + 0.5*sin(y)"}
    if typ == "global_norm":
        flat.update({"global_norm.gamma_1": "y**2", "global_norm.gamma_hat": "3 + w",
                     "global_norm.conditions": "warn"})
    flat.update({f"{typ}.{k}": v for k, v in over.items()})
    return flat


def _variants():
    """name: (flat parameters, plant, n_states)."""
    return {
        "di_stop_foh": (_flat("double_integrator_prescribed_time", mode="stop", g_max=1e4,
                              input_hold="foh"), "chain", 2),
        "di_constant": (_flat("double_integrator_prescribed_time", mode="constant", t_stop=4.5),
                        "chain", 2),
        "di_restart_no_keep": (_flat("double_integrator_prescribed_time", T=0.4567,
                                     reset_keeps_estimate=False), "chain", 2),
        "chain6_restart": (_chain(6), "chain", 6),
        "chain6_constant": (_chain(6, mode="constant"), "chain", 6),
        "gn_vdp_reduced_foh": (_flat("van_der_pol_global_norm", form="reduced", output_hold="foh"),
                               "vdp", 2),
        "gn_3": (_companion("global_norm", 3), "companion", 3),
        "gn_4": (_companion("global_norm", 4), "companion", 4),
        "hg_vdp_estimate_foh": (_flat("van_der_pol_high_gain", model_input="estimate",
                                      output_hold="foh"), "vdp", 2),
        "hg_3": (_companion("high_gain", 3, L=5.0), "companion", 3),
    }


def _times():
    """Irregular 1 kHz stamps on the 1 us grid with a 0.6 s gap at 6 s."""
    rng = np.random.default_rng(1)
    t = np.arange(int(T_END * 1000) + 1) * 1e-3
    t[1:-1] += rng.uniform(-0.3, 0.3, len(t) - 2) * 1e-3
    t = np.round(t * 1e6) / 1e6
    return t[(t < 6.0) | (t > 6.6)]


def _stream(plant: str, n: int):
    """(t, u, y): a chain of n integrators driven by u (held between samples, exact), van der
    Pol from (2, 0), or the n-state chain of _companion from (1, 0, ..., -1)."""
    from scipy.integrate import solve_ivp
    from scipy.linalg import expm
    t = _times()
    if plant == "chain":
        u = np.sin(10 * t) + np.cos(t)
        A = np.diag(np.ones(n - 1), 1)
        x = np.linspace(20.0, 1.0, n)
        y = [x[0]]
        for k in range(len(t) - 1):
            h = t[k + 1] - t[k]
            M = np.zeros((n + 1, n + 1))
            M[:n, :n] = A * h
            M[n - 1, n] = h
            E = expm(M)
            x = E[:n, :n] @ x + E[:n, n] * u[k]
            y.append(x[0])
        return t, u, np.array(y)
    if plant == "vdp":
        def rhs(_, x):
            return [x[1], (1 - x[0] ** 2) * x[1] - x[0]]
        x0 = [2.0, 0.0]
    else:
        coef = np.poly(-np.ones(n))[1:][::-1]

        def rhs(_, x):
            return list(x[1:]) + [-float(np.dot(coef, x)) + 0.5 * math.sin(x[0])]
        x0 = [1.0] + [0.0] * (n - 2) + [-1.0]
    s = solve_ivp(rhs, (0.0, t[-1]), x0, t_eval=t, method="DOP853", rtol=1e-11, atol=1e-12)
    return t, np.zeros(len(t)), s.y[0]


def _feed(flat, plant, n):
    """The outputs of a Runner on the stream, with a reset at 0.5 s and a restart from a
    given state at 8.5 s: per sample the status (0 output, else 1), the output's values and,
    for prescribed_time, what the observer's state says (after the window, frozen gains,
    window restarts, the last end at the sampling limit)."""
    from fto_ros.runner import Runner
    from fto_ros.runner.runner import Output
    t, u, y = _stream(plant, n)
    r = Runner(flat)
    m = r.observer.n_inputs
    pt = r.observer.TYPE == "prescribed_time"
    status, est, conv, phase = [], [], [], []
    for k in range(len(t)):
        if k and t[k - 1] < 0.5 <= t[k]:
            r.reset("service")
        if k and t[k - 1] < 8.5 <= t[k]:
            r.set_state(np.full(n, 0.5))
        if m:
            r.set_input(t[k], [u[k]])
        out = r.process(t[k], [y[k]])
        ok = isinstance(out, Output)
        status.append(0 if ok else 1)
        est.append(out.estimate if ok else np.full(n, np.nan))
        conv.append(out.convergence if ok else np.full(5, np.nan))
        obs = r.observer
        phase.append((obs.after_window, obs._frozen is not None, obs.restarts_total,
                      obs.last_end is not None and obs.last_end[1] == "sampling limit")
                     if pt else (0, 0, 0, 0))
    return np.array(status), np.array(est), np.array(conv), np.array(phase, dtype=float)


def run_all(path: str) -> None:
    """Every case's outputs into the npz file at path (what each subprocess does)."""
    import warnings

    import reference_runs as RR
    from fto_ros.core import jit as J
    warnings.simplefilter("ignore", UserWarning)       # the footnote-6 warnings asked for
    out = {"numba": np.array(J.ENABLED)}
    for i, p in enumerate(_pairs()):
        log, _ = RR.log_replay(RR.ROOT / "bags" / p["bag"], [RR.ROOT / f for f in p["params"]])
        status, est, _, conv = RR.outputs(log, 1)
        out[f"pair{i}_status"] = np.array([hash(s) for s in status])
        out[f"pair{i}_est"], out[f"pair{i}_conv"] = est, conv
    for name, (flat, plant, n) in _variants().items():
        (out[f"{name}_status"], out[f"{name}_est"], out[f"{name}_conv"],
         out[f"{name}_phase"]) = _feed(flat, plant, n)
    np.savez(path, **out)


def _side(tmp_path: Path, numba: bool) -> dict:
    path = tmp_path / f"numba{int(numba)}.npz"
    env = dict(os.environ, FTO_ROS_NUMBA="1" if numba else "0", PYTHONHASHSEED="0")
    code = (f"import sys; sys.path[:0] = [{str(Path(__file__).parent)!r}, {str(ROOT / 'test' / 'support')!r}, {str(ROOT)!r}]; "
            f"import test_compiled_paths as m; m.run_all({str(path)!r})")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, check=True, timeout=3600)
    return dict(np.load(path))


@pytest.mark.slow
def test_compiled_and_numpy_paths_give_the_same_outputs(tmp_path):
    pytest.importorskip("numba")
    compiled = _side(tmp_path, True)
    plain = _side(tmp_path, False)
    assert bool(compiled.pop("numba")) and not bool(plain.pop("numba"))
    assert sorted(compiled) == sorted(plain)
    assert len(compiled) == 3 * len(_pairs()) + 4 * len(_variants())
    for key in sorted(compiled):
        a, b = compiled[key], plain[key]
        assert a.shape == b.shape and a.size, key
        assert np.array_equal(a, b, equal_nan=True), \
            f"{key}: largest difference {np.nanmax(np.abs(a - b)):.3g}"
    # the variants reach what they are for: outputs on nearly every sample, and for
    # prescribed_time (after the window, frozen gains, window restarts, an end at the
    # sampling limit)
    reached = {"di_stop_foh": (1, 0, 0, 0), "di_constant": (1, 1, 0, 0),
               "di_restart_no_keep": (0, 0, 1, 0), "chain6_restart": (0, 0, 1, 1),
               "chain6_constant": (1, 1, 0, 1)}
    for name in _variants():
        assert (compiled[f"{name}_status"] == 0).mean() > 0.99, name
        seen = compiled[f"{name}_phase"].max(axis=0) > 0
        assert tuple(int(v) for v in seen) == reached.get(name, (0, 0, 0, 0)), (name, seen)
