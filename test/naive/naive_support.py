"""What every naive reference shares: the samples it is fed, the runner run over the same
samples, and the comparison at every sample.

Nothing here (nor in any naive reference) imports the package's numerics (fto_ros.core,
fto_ros.observers): the references are written from the papers' equations and the
families' docs pages in plain numpy/scipy.  The package is reached through its runner only,
built from committed params files (``Runner(load_params_files(...))``), exactly as the
replay and the node build it.

- ``times(...)``: sample stamps in whole microseconds (the runner counts model time in
  1 us quanta), regular or irregular;
- ``simulate(rhs, x0, t, u)``: the plant between the stamps with the input held (a DAC),
  scipy's DOP853 at rtol 1e-12; the references and the package get the same samples, so
  the plant's accuracy does not enter any comparison;
- ``run(flat, t, y, u)``: the package's estimates (and unknown-input estimates) at every
  sample, through ``Runner.set_input`` / ``Runner.process``; every sample must be accepted;
- ``assert_close(name, got, ref, tol)``: the largest deviation at any sample, relative to
  each state's scale (max(1, largest |value| of the reference over the run)), within tol.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from fto_ros.runner import Output, Runner
from fto_ros.runner.params_file import load_params_file, load_params_files

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config"
EPS = np.finfo(float).eps


def flat_params(*names: str, **overrides) -> dict:
    """The merged committed params files config/<name>.yaml, then ``overrides`` (dotted
    names given with '__' for '.', e.g. single_delay__tau=0.05)."""
    flat = load_params_files([CONFIG / f"{n}.yaml" for n in names])
    flat.update({k.replace("__", "."): v for k, v in overrides.items()})
    return flat


def plant_constants(name: str) -> dict[str, float]:
    """The ``plant.constants`` of config/<name>.yaml as {name: value}."""
    flat = load_params_file(CONFIG / f"{name}.yaml")
    return {k.strip(): float(v) for k, v in (c.split("=") for c in flat["plant.constants"])}


def times(t0: float, n: int, period_us: int, jitter_us: tuple[int, ...] = (0,),
          seed: int = 0) -> np.ndarray:
    """n stamps from t0 (seconds, a whole number of microseconds), period_us apart plus a
    jitter drawn from ``jitter_us`` (seeded): whole microseconds, as the runner counts."""
    rng = np.random.default_rng(seed)
    steps = period_us + rng.choice(np.asarray(jitter_us), size=n - 1)
    us = round(t0 * 1e6) + np.concatenate(([0], np.cumsum(steps)))
    return us / 1e6


def steps(t: np.ndarray) -> np.ndarray:
    """The intervals between the stamps as the runner takes them: whole microseconds."""
    return np.diff(np.round(t * 1e6)) * 1e-6


def simulate(rhs, x0, t: np.ndarray, u: np.ndarray | None) -> np.ndarray:
    """The plant x' = rhs(x, u) at the stamps t, u[k] held on [t_k, t_k+1)."""
    x = np.empty((len(t), len(x0)))
    x[0] = x0
    for k in range(len(t) - 1):
        uk = u[k] if u is not None else np.zeros(0)
        sol = solve_ivp(lambda s, z: rhs(z, uk), (t[k], t[k + 1]), x[k], method="DOP853",
                        rtol=1e-12, atol=1e-12)
        x[k + 1] = sol.y[:, -1]
    return x


def run(flat: dict, t: np.ndarray, y: np.ndarray, u: np.ndarray | None = None):
    """(estimates, unknown-input estimates or None, convergence values) of the package at
    every sample: set_input(t_k, u_k) then process(t_k, y_k); every sample must be
    accepted."""
    r = Runner(flat)
    est, ui, conv = [], [], []
    for k in range(len(t)):
        if u is not None:
            bad = r.set_input(float(t[k]), np.asarray(u[k], float))
            assert bad is None, f"input {k} at t = {t[k]} refused: {bad}"
        out = r.process(float(t[k]), np.asarray(y[k], float))
        assert isinstance(out, Output), f"sample {k} at t = {t[k]} not accepted: {out}"
        est.append(out.estimate)
        ui.append(out.unknown_input)
        conv.append(out.convergence)
    ui = None if ui[0] is None else np.array(ui)
    return np.array(est), ui, np.array(conv)


def deviation(got: np.ndarray, ref: np.ndarray) -> tuple[float, int]:
    """(largest |got - ref| relative to each column's scale, the sample where it is)."""
    got, ref = np.atleast_2d(np.asarray(got, float).T).T, np.atleast_2d(np.asarray(ref, float).T).T
    assert got.shape == ref.shape, f"shapes {got.shape} and {ref.shape}"
    scale = np.maximum(1.0, np.abs(ref).max(axis=0))
    rel = np.abs(got - ref) / scale
    k = int(np.nanargmax(rel.max(axis=1))) if np.isfinite(rel).all() else \
        int(np.argmax(~np.isfinite(rel).all(axis=1)))
    return float(rel.max()) if np.isfinite(rel).all() else math.inf, k


def assert_close(name: str, got, ref, tol: float) -> float:
    """Every sample of ``got`` within ``tol`` of ``ref`` (relative to each state's scale);
    returns the largest deviation, printed with the test's output."""
    err, k = deviation(got, ref)
    print(f"{name}: largest deviation {err:.3g} of the state's scale (bar {tol:.1g}), "
          f"at sample {k}")
    assert err <= tol, (f"{name}: the package and the naive reference differ by {err:.3g} of "
                        f"the state's scale at sample {k} (bar {tol:.1g}): package "
                        f"{np.asarray(got)[k]}, reference {np.asarray(ref)[k]}")
    return err


def linear_hold_step(A: np.ndarray, B: np.ndarray, x: np.ndarray, w0: np.ndarray,
                     w1: np.ndarray, h: float) -> np.ndarray:
    """x(h) of x' = A x + B w(s), w linear from w0 (s = 0) to w1 (s = h): one expm of the
    augmented system z = (x, w(s), dw/ds), computed afresh each call (no cache)."""
    n, m = B.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n] = A
    M[:n, n:n + m] = B
    M[n:n + m, n + m:] = np.eye(m)
    z = np.concatenate((x, w0, (w1 - w0) / h))
    return (expm(M * h) @ z)[:n]
