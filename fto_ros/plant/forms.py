"""The structural forms the observers' papers need, read off a plant symbolically (ROS-free).

- :func:`linear_form`: ``f = A x + B u + D d + R(y, u)``, ``y = C x``: the constant
  coefficients of the states, known and unknown inputs, and a remainder that may depend on
  the measured states (those some output picks, ``y_i = c x_j``) and the known inputs only.
  A coefficient that depends on a state, or a remainder that depends on an unmeasured
  state, is refused naming the expression and the term that breaks it.
- :func:`canonical_form`: the observer canonical form (a, b) of an LTI SISO plant and the
  map x_c = T x, in exact rational arithmetic (the floats of the plant are exact binary
  fractions), so no digit is lost on the way.
- :func:`chain_form`: the observability form x0' = x1, ..., x_{n-1}' = f_n(x, u), y = x0,
  through the Lie derivatives z_k = L_f^k h when they are linear in the state
  (z = T x with T constant).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy

from ..core.errors import ConfigError
from .block import Plant, number, to_text

LINEAR_CLASS = "a linear plant (up to known terms in the measured outputs and inputs)"


def _is_constant(e: sympy.Expr) -> bool:
    return not e.free_symbols


def _coefficient(expr: sympy.Expr, s: sympy.Symbol) -> sympy.Expr | None:
    """d expr / d s when it is a constant (expanded if needed), else None."""
    c = sympy.diff(expr, s)
    if _is_constant(c):
        return c
    c = sympy.expand(c)
    return c if _is_constant(c) else None


def offending_term(expr: sympy.Expr, s: sympy.Symbol) -> sympy.Expr:
    """The term of ``expr`` (a sum) in which ``s`` does not enter linearly with a constant
    coefficient: what a refusal names."""
    for term in sympy.Add.make_args(expr):
        if term.has(s) and _coefficient(term, s) is None:
            return term
    return expr


@dataclass
class LinearForm:
    """``f = A x + B u + D d + R``, ``y = C x``; ``R`` in the plant's symbols, free of
    everything but the measured states and the known inputs; ``measured[j] = (i, c)`` when
    output i is ``c x_j``."""

    A: np.ndarray
    B: np.ndarray
    D: np.ndarray
    C: np.ndarray
    R: list[sympy.Expr]
    measured: dict[int, tuple[int, float]]

    def output_names(self, plant: Plant) -> dict[sympy.Symbol, sympy.Expr]:
        """The renaming that writes R in an observer's vocabulary: measured state x_j ->
        y_i / c, input j -> u_j."""
        ren: dict[sympy.Symbol, sympy.Expr] = {}
        for j, (i, c) in self.measured.items():
            y = sympy.Symbol(f"y{i}", real=True)
            ren[plant.x[j]] = y if c == 1.0 else y / sympy.Float(c)
        ren.update({s: sympy.Symbol(f"u{k}", real=True) for k, s in enumerate(plant.u)})
        return ren

    def terms(self, plant: Plant, rows=None) -> list[str]:
        """R (rows of it) as text in y0.. and u0.."""
        ren = self.output_names(plant)
        rows = range(len(self.R)) if rows is None else rows
        return [to_text(self.R[i], ren) for i in rows]


def output_matrix(plant: Plant, who: str) -> tuple[np.ndarray, dict[int, tuple[int, float]]]:
    """C with y = C x (outputs linear in the states, no input feedthrough, no offset) and
    the directly measured states, or ConfigError naming plant.h[i]."""
    C = np.zeros((plant.p, plant.n))
    measured: dict[int, tuple[int, float]] = {}
    for i, e in enumerate(plant.h):
        where = plant.where("h", i)
        for s in plant.u:
            if e.has(s):
                raise ConfigError(where, f"{who} needs outputs without input feedthrough: "
                                  f"{where} has {offending_term(e, s)}")
        rest = e
        for j, s in enumerate(plant.x):
            c = _coefficient(e, s)
            if c is None:
                raise ConfigError(where, f"{who} needs outputs linear in the states: {where} "
                                  f"has {offending_term(e, s)}")
            C[i, j] = number(c)
            rest = rest - c * s
        if sympy.expand(rest) != 0:
            raise ConfigError(where, f"{who} needs outputs linear in the states: {where} has "
                              f"the offset {sympy.expand(rest)}")
        nz = np.flatnonzero(C[i])
        if nz.size == 1 and int(nz[0]) not in measured:
            measured[int(nz[0])] = (i, float(C[i, nz[0]]))
    return C, measured


def linear_form(plant: Plant, who: str, unknown_inputs: bool = False) -> LinearForm:
    """The split of f into constant-coefficient linear parts and a remainder R(y, u).

    ``unknown_inputs``: keep the unknown inputs (their coefficients become D); otherwise
    they are taken as zero (the nominal plant)."""
    C, measured = output_matrix(plant, who)
    n, m, q = plant.n, plant.m, plant.q
    f = plant.f if unknown_inputs else plant.nominal(plant.f)
    A, B, D = np.zeros((n, n)), np.zeros((n, m)), np.zeros((n, q))
    allowed = {plant.x[j] for j in measured} | set(plant.u)
    R = []
    for i, e in enumerate(f):
        where = plant.where("f", i)
        rest = e
        for syms, M, kind in ((plant.x, A, "state"), (plant.u, B, "input"),
                              (plant.d, D, "unknown input")):
            for j, s in enumerate(syms):
                if not e.has(s):
                    continue
                c = _coefficient(e, s)
                if c is None:
                    if kind == "state" and j not in measured or kind == "unknown input":
                        what = "not measured" if kind == "state" else "an unknown input"
                        raise ConfigError(where, f"{who} needs {LINEAR_CLASS}: {where} has "
                                          f"{offending_term(e, s)} ({s} is {what})")
                    continue            # a measured state or a known input: part of R
                M[i, j] = number(c)
                rest = rest - c * s
        if rest.free_symbols - allowed:      # e.g. 3*(v + x) - 3*v: expand to cancel
            rest = sympy.expand(rest)
        bad = sorted((s.name for s in rest.free_symbols - allowed))
        if bad:
            s = sympy.Symbol(bad[0], real=True)
            raise ConfigError(where, f"{who} needs {LINEAR_CLASS}: {where} has "
                              f"{offending_term(e, s)} ({bad[0]} is not measured)")
        R.append(rest)
    return LinearForm(A=A, B=B, D=D, C=C, R=R, measured=measured)


# ------------------------------------------------------------------ canonical form
def _exact(M: np.ndarray) -> sympy.Matrix:
    """A float matrix as exact rationals (each float is an exact binary fraction)."""
    return sympy.Matrix(M.shape[0], M.shape[1], [sympy.Rational(float(v)) for v in M.ravel()])


@dataclass
class CanonicalForm:
    """x_c = T x;  x_c' = (S - a e1') x_c + [0; b] u + T R,  y = x_c1."""

    a: list[float]          # (a_{n-1}, ..., a_0)
    b: list[float]          # (b_rho, ..., b_0); empty without an input
    r: int                  # relative degree (n without an input)
    T: np.ndarray
    T_exact: sympy.Matrix
    cond: float


def canonical_form(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> CanonicalForm | None:
    """The observer canonical form of (A, B, C), single output, at most one input; None
    when (A, C) is not observable."""
    n = A.shape[0]
    Ae, Ce = _exact(A), _exact(C)
    O = sympy.Matrix.vstack(*[Ce * Ae ** k for k in range(n)])
    if O.rank() < n:
        return None
    s = sympy.Symbol("s")
    coeffs = Ae.charpoly(s).all_coeffs()[1:]          # s^n + a_{n-1} s^(n-1) + ... + a_0
    Ac = sympy.zeros(n, n)
    for i in range(n):
        Ac[i, 0] = -coeffs[i]
        if i + 1 < n:
            Ac[i, i + 1] = 1
    e1 = sympy.zeros(1, n)
    e1[0, 0] = 1
    Oc = sympy.Matrix.vstack(*[e1 * Ac ** k for k in range(n)])
    T = Oc.inv() * O
    a = [float(c) for c in coeffs]
    b, r = [], n
    if B.shape[1]:
        bc = T * _exact(B)
        r = next((k + 1 for k in range(n) if bc[k] != 0), n)
        b = [float(v) for v in bc[r - 1:]]
    Tf = np.array(T.evalf(20).tolist(), dtype=float)
    return CanonicalForm(a=a, b=b, r=r, T=Tf, T_exact=T, cond=float(np.linalg.cond(Tf)))


# ---------------------------------------------------------------------- chain form
@dataclass
class ChainForm:
    """z = T x;  z_k' = z_{k+1} (k < n-1),  z_{n-1}' = f_n(z, u),  y = z_0."""

    T: np.ndarray
    f_n: str                 # in y (for z_0), x1 .. x_{n-1}, u0 ..
    identity: bool


def chain_form(plant: Plant, who: str) -> ChainForm:
    """The observability form by Lie derivatives of h (nominal f), when they are linear in
    the state up to order n - 1, or ConfigError naming what breaks it."""
    if plant.p != 1:
        raise ConfigError("plant.h", f"{who} needs one output (the observability form y = x0), "
                          f"got {plant.p}")
    output_matrix(plant, who)                     # linear, no feedthrough, no offset
    n, f = plant.n, plant.nominal(plant.f)
    z = [plant.h[0]]
    rows: list[list[sympy.Expr]] = []
    for k in range(n):
        zk = z[-1]
        for s in plant.x + plant.u:
            if (s in plant.u and zk.has(s)) or (s in plant.x and _coefficient(zk, s) is None):
                _refuse_chain(plant, f, rows, k, zk, s, who)
        rows.append([_coefficient(zk, s) for s in plant.x])
        z.append(sum((sympy.diff(zk, s) * fs for s, fs in zip(plant.x, f)), sympy.Integer(0)))
    T = sympy.Matrix(rows).applyfunc(lambda v: sympy.Rational(float(v)))
    if T.rank() < n:
        raise ConfigError("plant.h", f"{who}: the output and its first {n - 1} derivatives do "
                          f"not determine the state (rank {T.rank()} < {n})")
    identity = T == sympy.eye(n)
    zs = [sympy.Symbol("y", real=True)] + [sympy.Symbol(f"x{i}", real=True) for i in range(1, n)]
    if identity:
        back = dict(zip(plant.x, zs))
    else:
        Ti = T.inv()
        back = {plant.x[j]: sum((sympy.Float(float(Ti[j, k])) * zs[k] for k in range(n)
                                 if Ti[j, k] != 0), sympy.Integer(0)) for j in range(n)}
    ren = {s: sympy.Symbol(f"u{k}", real=True) for k, s in enumerate(plant.u)}
    f_n = to_text(z[-1], {**back, **ren})
    return ChainForm(T=np.array(T.evalf(20).tolist(), dtype=float), f_n=f_n, identity=identity)


def _refuse_chain(plant: Plant, f, rows, k: int, zk: sympy.Expr, s: sympy.Symbol, who: str):
    """ConfigError for derivative k of the output, which is not linear in the states (or
    has an input before the last equation): name the f[j] that brought the term in."""
    what = ("the plant in observability form up to a constant linear map" if s in plant.x else
            "the known inputs in the last equation of the observability form only")
    if k > 0:
        for j, c in enumerate(rows[k - 1]):
            if c == 0:
                continue
            for s2 in plant.x + plant.u:
                if (s2 in plant.u and f[j].has(s2)) or (s2 in plant.x and _coefficient(f[j], s2) is None):
                    where = plant.where("f", j)
                    raise ConfigError(where, f"{who} needs {what}: {where} has "
                                      f"{offending_term(f[j], s2)} (in derivative {k} of the "
                                      f"output, {zk})")
    raise ConfigError(plant.where("h", 0), f"{who} needs {what}: derivative {k} of the output "
                      f"is {zk}")
