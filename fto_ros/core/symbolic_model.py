"""A nonlinear plant written once as text, its observability map derived and compiled.

Plant (Possieri, Vidano & Novara 2020, eq. 1), single output::

    x' = f(x, u),   y = h(x, u),   x in R^n, u in R^m

given as expressions in the user's state and input names (plus named constants).
The observability map of order n (eq. 2-3) uses the input and its derivatives
u_e = (u, u', ..., u^(n))::

    D^0 h = h(x, u)
    D^(k+1) h = d(D^k h)/dx f(x, u) + sum_j sum_d d(D^k h)/d u_j^(d) u_j^(d+1)
    O_(n-1)(x, u_e) = [D^0 h, ..., D^(n-1) h]

Derived once with sympy: O, its Jacobian J = dO/dx and the input feed-forward
G = dO/du_e . u_e^(1,n) (the term the observer (11g) subtracts), then generated as one
model function (core/model_code.py: ``fn(x, y, u, out)`` with u the input-derivative
vector, compiled for the observer's kernel) that writes (O, J row-major, G) at a point.
A numpy version of J is compiled for the start-up check over a box.

Constants: ``constants: ["a1=35.0", "b1=1/L"]`` -- ``name=expression`` in numbers and
the constants defined before it; they are substituted as numbers before the
derivation.  ROS-free; ConfigError names the parameter.
"""
from __future__ import annotations

import itertools
import keyword
import math
import re
from typing import Sequence

import numpy as np
import sympy

from .errors import ConfigError
from .expressions import FUNCTIONS, parse
from .model_code import ModelFunction

#: a name, matched whole (fullmatch: ``$`` would also match before a final newline, "q\n")
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
#: names a user may not take (sympy's parser needs them, or they are functions/constants)
_RESERVED = set(FUNCTIONS) | {"pi", "E", "Integer", "Float", "Rational", "Symbol", "t"}


#: most names in one list (states, inputs, unknown inputs) and most constants: the largest
#: observer takes 64 states; checked before anything is parsed
MAX_NAMES = 64
MAX_CONSTANTS = 256


def check_names(names: Sequence[str], parameter: str, taken: set[str]) -> None:
    if len(names) > MAX_NAMES:
        raise ConfigError(parameter, f"{len(names)} names: at most {MAX_NAMES}")
    for name in names:
        if not isinstance(name, str) or not _NAME.fullmatch(name) or keyword.iskeyword(name):
            raise ConfigError(parameter, f"{name!r} is not a valid name (letters, digits and _ "
                              "starting with a letter, not a Python keyword)")
        if name in _RESERVED:
            raise ConfigError(parameter, f"{name!r} is reserved (a function or constant name)")
        if "__" in name:
            raise ConfigError(parameter, f"{name!r}: '__' is not allowed in a name")
        if name in taken:
            raise ConfigError(parameter, f"the name {name!r} is used twice")
        taken.add(name)


def parse_constants(texts: Sequence[str], parameter: str, taken: set[str]) -> dict[str, float]:
    """``["a1=35", "b=2*a1"]`` -> {"a1": 35.0, "b": 70.0}; each may use the earlier ones."""
    if len(texts) > MAX_CONSTANTS:
        raise ConfigError(parameter, f"{len(texts)} constants: at most {MAX_CONSTANTS}")
    values: dict[str, float] = {}
    syms: dict[str, sympy.Symbol] = {}
    for i, text in enumerate(texts):
        where = f"{parameter}[{i}]"
        if not isinstance(text, str) or text.count("=") != 1:
            raise ConfigError(where, f"expected 'name=value', got {text!r}")
        name, expr_text = (s.strip() for s in text.split("="))
        check_names([name], where, taken)
        expr = parse(expr_text, list(syms.values()), where)
        val = expr.xreplace({s: sympy.Float(values[s.name]) for s in expr.free_symbols})
        try:
            num = float(val)
        except (TypeError, ValueError):
            raise ConfigError(where, f"{text!r} does not evaluate to a number") from None
        if not math.isfinite(num):
            raise ConfigError(where, f"{text!r} is not finite")
        values[name] = num
        syms[name] = sympy.Symbol(name, real=True)
    return values


class SymbolicModel:
    """f, h as text -> observability map O_(n-1), J = dO/dx, G = dO/du_e u_e^(1,n), compiled.

    ``ue`` (the input-derivative vector every function takes) is laid out input by
    input: ``[u_0, u_0', ..., u_0^(n), u_1, ..., u_1^(n), ...]`` (length m (n + 1)).
    """

    def __init__(self, states: Sequence[str], inputs: Sequence[str], f: Sequence[str],
                 h: Sequence[str], constants: Sequence[str] = (), prefix: str = ""):
        P = prefix
        states, inputs = list(states or []), list(inputs or [])
        if not states:
            raise ConfigError(P + "states", "give the state names, e.g. [q, q_dot, current]")
        taken: set[str] = set()
        check_names(states, P + "states", taken)
        check_names(inputs, P + "inputs", taken)
        consts = parse_constants(list(constants or []), P + "constants", taken)
        n, m = len(states), len(inputs)
        if f is None or len(f) != n:
            raise ConfigError(P + "f", f"expected {n} expression(s), one per state "
                              f"({', '.join(states)}), got {0 if f is None else len(f)}")
        if h is None or len(h) != 1:
            raise ConfigError(P + "h", "expected exactly one output expression (the paper's "
                              f"single-output setting), got {0 if h is None else len(h)}")
        self.states, self.inputs, self.constants = states, inputs, consts
        self.n, self.m = n, m
        self.x = [sympy.Symbol(s, real=True) for s in states]
        u0 = [sympy.Symbol(s, real=True) for s in inputs]
        # u[j][d] = d-th derivative of input j (d = 0..n)
        self.u = [[u0[j]] + [sympy.Dummy(f"{inputs[j]}_d{d}", real=True) for d in range(1, n + 1)]
                  for j in range(m)]
        c_syms = [sympy.Symbol(k, real=True) for k in consts]
        allowed = self.x + u0 + c_syms
        subs = {s: sympy.Float(consts[s.name]) for s in c_syms}
        self.f = [parse(t, allowed, f"{P}f[{i}]").xreplace(subs) for i, t in enumerate(f)]
        self.h = parse(h[0], allowed, f"{P}h[0]").xreplace(subs)
        self.ue = [s for row in self.u for s in row]
        for name, exprs in (("f", self.f), ("h", [self.h])):
            for i, e in enumerate(exprs):
                if e.has(sympy.zoo, sympy.nan, sympy.oo, -sympy.oo):
                    raise ConfigError(f"{P}{name}[{i}]", f"{(f if name == 'f' else h)[i]!r} is not "
                                      f"finite (it simplifies to {e})")

        # -- observability map (2)-(3) and the feed-forward G -------------------------------
        rows = [self.h]
        G = []
        for k in range(n):
            Dk = rows[-1]
            drift = sum((sympy.diff(Dk, xi) * fi for xi, fi in zip(self.x, self.f)), sympy.Integer(0))
            ff = sum((sympy.diff(Dk, self.u[j][d]) * self.u[j][d + 1]
                      for j in range(m) for d in range(n)), sympy.Integer(0))
            G.append(ff)
            if k < n - 1:
                rows.append(drift + ff)
        self.O = rows                                   # n expressions, D^0 h .. D^(n-1) h
        self.G = G                                      # n expressions: dO/du_e u_e^(1,n)
        self.J = [[sympy.diff(r, xi) for xi in self.x] for r in self.O]
        # highest derivative of each input the observer needs (in O or in G)
        used = set().union(*(e.free_symbols for e in self.O + self.G))
        in_J = set().union(*(e.free_symbols for r in self.J for e in r))
        self._ue_in_J = [[self.u[j][d] in in_J for d in range(n + 1)] for j in range(m)]
        self.input_orders = [max([d for d in range(n + 1) if self.u[j][d] in used], default=-1)
                             for j in range(m)]
        self.uses_input_derivatives = any(k >= 1 for k in self.input_orders)
        for i, e in enumerate(self.O + [x for r in self.J for x in r] + self.G):
            if e.has(sympy.zoo, sympy.nan, sympy.oo, -sympy.oo):
                raise ConfigError(P + "f", f"the observability map is not finite "
                                  f"(expression {i} is {e})")

        # -- compilation ------------------------------------------------------------------
        flat = list(self.O) + [x for r in self.J for x in r] + list(self.G)
        #: [O, J row-major, G](x, u_e) as a model function (its ``u`` is u_e)
        self.function = ModelFunction(flat, [self.x, [], self.ue])
        self._out = np.zeros(len(flat))
        self._jac_np = sympy.lambdify((self.x, self.ue), [x for r in self.J for x in r],
                                      modules="numpy", cse=True)

    # -- numeric evaluation -------------------------------------------------------------------
    def evaluate(self, x, ue) -> tuple | None:
        """(O, J row-major, G) as one flat tuple of floats (length n + n^2 + n), or None
        where the expressions are not defined or not finite (log of a negative, division
        by zero...)."""
        if self.function.pure(x, (), ue, self._out) != 0:
            return None
        return tuple(self._out.tolist())

    def observation(self, x, ue) -> tuple | None:
        """O_(n-1)(x, u_e) as a tuple, or None where undefined."""
        out = self.evaluate(x, ue)
        return None if out is None else out[:self.n]

    def jacobian(self, x, ue) -> np.ndarray:
        """J at one point, (n, n) array (NaN where undefined)."""
        out = self.evaluate(list(x), list(ue))
        n = self.n
        if out is None:
            return np.full((n, n), np.nan)
        return np.array(out[n:n + n * n], dtype=float).reshape(n, n)

    def jacobians(self, X: np.ndarray, UE: np.ndarray) -> np.ndarray:
        """J at many points: X (k, n), UE (k, m (n + 1)) -> (k, n, n) (vectorised numpy)."""
        X = np.asarray(X, dtype=float)
        UE = np.asarray(UE, dtype=float).reshape(X.shape[0], -1)
        k, n = X.shape[0], self.n
        with np.errstate(all="ignore"):
            entries = self._jac_np(list(X.T), list(UE.T))
        J = np.empty((k, n * n))
        for i, e in enumerate(entries):
            J[:, i] = np.broadcast_to(np.asarray(e, dtype=float), (k,))
        return J.reshape(k, n, n)

    # -- start-up check ---------------------------------------------------------------------
    def check(self, x0, ue0, *, box: Sequence[float] = (), input_box: Sequence[float] = (),
              grid: int = 9, max_condition: float = 1e8, prefix: str = "") -> dict:
        """Rank and conditioning of J at x0 (with ue0) and over a box; ConfigError if singular.

        ``box``: [lo_0, hi_0, lo_1, hi_1, ...] for the states; ``input_box``: [lo, hi] per
        input, applied to the input and each of its derivatives J depends on (the paper's
        |u_e| <= 10).  The box is sampled on a grid of ``grid`` points per dimension (capped
        at ~20000 points).  Returns a report dict (also for the diagnostics).
        """
        P, n = prefix, self.n
        J0 = self.jacobian(x0, ue0)
        where = f"x_hat(0) = {_fmt(x0)}" + (f", u_e = {_fmt(ue0)}" if self.m else "")
        if not np.all(np.isfinite(J0)):
            raise ConfigError(P + "h", f"the observability map's Jacobian is not defined at {where}")
        sv = np.linalg.svd(J0, compute_uv=False)
        rank = int(np.sum(sv > sv[0] * 1e-12)) if sv[0] > 0 else 0
        cond0 = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
        report = {"rank_at_x0": rank, "cond_at_x0": cond0, "sigma_at_x0": sv.tolist()}
        if rank < n or not cond0 <= max_condition:
            raise ConfigError(P + "h", f"observability map singular at {where}: rank {rank} < {n}"
                              if rank < n else
                              f"observability map ill-conditioned at {where}: cond(J) = "
                              f"{cond0:.3g} > max_condition = {max_condition:g}")
        if len(box) == 0 and len(input_box) == 0:
            return report
        if len(box) not in (0, 2 * n):
            raise ConfigError(P + "check_box", f"expected 2 n = {2 * n} values [lo, hi] per "
                              f"state, got {len(box)}")
        if len(input_box) not in (0, 2 * self.m):
            raise ConfigError(P + "check_input_box", f"expected 2 values [lo, hi] per input "
                              f"({2 * self.m}), got {len(input_box)}")
        axes = []
        for i in range(n):
            if box:
                lo, hi = box[2 * i], box[2 * i + 1]
                if not lo <= hi:
                    raise ConfigError(P + "check_box", f"state {self.states[i]}: lo {lo} > hi {hi}")
                axes.append(np.linspace(lo, hi, grid) if hi > lo else np.array([lo]))
            else:
                axes.append(np.array([float(x0[i])]))
        ue_axes = []
        for j in range(self.m):
            for d in range(n + 1):
                if input_box and self._ue_in_J[j][d]:
                    lo, hi = input_box[2 * j], input_box[2 * j + 1]
                    if not lo <= hi:
                        raise ConfigError(P + "check_input_box", f"input {self.inputs[j]}: lo {lo} > hi {hi}")
                    ue_axes.append(np.linspace(lo, hi, grid) if hi > lo else np.array([lo]))
                else:
                    ue_axes.append(np.array([float(ue0[j * (n + 1) + d])]))
        all_axes = axes + ue_axes
        total = math.prod(len(a) for a in all_axes)
        if total > 20000:
            # thin every non-trivial axis evenly to stay near 20000 points
            live = [a for a in all_axes if len(a) > 1]
            per = max(2, int(20000 ** (1.0 / len(live))))
            all_axes = [np.linspace(a[0], a[-1], per) if len(a) > 1 else a for a in all_axes]
        pts = np.array(list(itertools.product(*all_axes)))
        J = self.jacobians(pts[:, :n], pts[:, n:])
        finite = np.all(np.isfinite(J.reshape(len(pts), -1)), axis=1)
        if not np.all(finite):
            bad = pts[np.argmin(finite)]
            raise ConfigError(P + "check_box", f"the observability map's Jacobian is not defined "
                              f"at x = {_fmt(bad[:n])}" + (f", u_e = {_fmt(bad[n:])}" if self.m else ""))
        s = np.linalg.svd(J, compute_uv=False)
        with np.errstate(divide="ignore"):
            cond = np.where(s[:, -1] > 0, s[:, 0] / np.maximum(s[:, -1], 1e-300), np.inf)
        worst = int(np.argmax(cond))
        report.update(box_points=len(pts), box_max_cond=float(cond[worst]),
                      box_min_sigma2=float(np.min(s[:, -1] ** 2)),
                      box_max_sigma2=float(np.max(s[:, 0] ** 2)))
        if not cond[worst] <= max_condition:
            bad = pts[worst]
            rank = int(np.sum(s[worst] > s[worst, 0] * 1e-12))
            what = f"rank {rank} < {n}" if rank < n else (
                f"cond(J) = {cond[worst]:.3g} > max_condition = {max_condition:g}")
            raise ConfigError(P + "check_box", f"observability map singular over the box at "
                              f"x = {_fmt(bad[:n])}" + (f", u_e = {_fmt(bad[n:])}" if self.m else "")
                              + f": {what}")
        return report


def _fmt(v) -> str:
    return "[" + ", ".join(f"{float(a):.4g}" for a in v) + "]"
