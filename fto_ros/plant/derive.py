"""From the plant block to each observer's explicit parameters (ROS-free).

``derive(observer_type, plant, section)`` returns exactly the parameters of today's explicit
form (the names in the observer's PARAMS, listed in :data:`DERIVES`), computed from the plant
and from the observer's own tuning values in ``section`` where the form needs one
(``single_delay.k``), or raises ConfigError naming the expression that puts the plant outside
the observer's class.  The observers without an unknown-input model run on the nominal plant
(unknown inputs taken as zero; the derivation says so in its notes).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np
import sympy

from ..core.errors import ConfigError
from ..core.linear import observability_rank
from ..core.structure import StructureError, invariant_zeros, relative_degree
from .block import Plant, to_text
from .forms import LinearForm, canonical_form, chain_form, linear_form, output_matrix

#: observer type -> the parameters derived from the plant block (a file giving one of them
#: explicitly as well is refused)
DERIVES: dict[str, tuple[str, ...]] = {
    "single_delay": ("n_unmeasured", "n_outputs", "n_inputs", "A1", "A2", "F1", "F2",
                     "lipschitz_K1", "lipschitz_K2", "state_map", "state_names"),
    "prescribed_time": ("n_states", "relative_degree", "n_inputs", "a", "b", "F", "state_map",
                        "state_names"),
    "hosm": ("n_states", "n_outputs", "n_inputs", "A", "B", "C", "D", "F", "state_names",
             "unknown_input_names"),
    "luenberger": ("n_states", "n_outputs", "n_inputs", "A", "B", "C", "F", "state_names"),
    "newton_inversion": ("states", "inputs", "constants", "f", "h"),
    "global_norm": ("n_states", "n_inputs", "f", "state_names", "chain_map"),
    "high_gain": ("n_states", "n_inputs", "f", "state_names", "chain_map"),
    "ekf": ("states", "inputs", "constants", "f", "h"),
    "joint_kalman": ("n_outputs", "state_names"),
}


@dataclass
class Derivation:
    """The derived parameters (short names), and the figures and notes for fto-design."""

    params: dict[str, Any]
    figures: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _flat(M: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(M, dtype=float).ravel()]


def _interval_bound(e: sympy.Expr) -> float | None:
    """sup |e| over every real value of its symbols, by interval arithmetic (an upper bound),
    or None when that is not finite."""
    try:
        b = e.subs({s: sympy.AccumBounds(-sympy.oo, sympy.oo) for s in e.free_symbols})
        lo, hi = (b.min, b.max) if isinstance(b, sympy.AccumBounds) else (b, b)
        v = max(abs(float(lo)), abs(float(hi)))
    except (TypeError, ValueError, AttributeError, NotImplementedError):
        return None
    return v if np.isfinite(v) else None


def lipschitz_bound(exprs: list[sympy.Expr], ys: list[sympy.Symbol]) -> float | None:
    """A Lipschitz constant in y of the vector ``exprs`` for all y and u: the Frobenius norm
    of the entry-wise interval bounds of d exprs / d y (>= the 2-norm of the Jacobian);
    None when an entry is unbounded."""
    bounds = []
    for e in exprs:
        for y in ys:
            b = _interval_bound(sympy.diff(e, y))
            if b is None:
                return None
            bounds.append(b)
    return float(np.sqrt(np.sum(np.square(bounds)))) if bounds else 0.0


def _nominal_note(plant: Plant, who: str) -> list[str]:
    if not plant.q:
        return []
    return [f"{who} has no unknown-input model: it runs on the nominal plant "
            f"({', '.join(plant.unknown_inputs)} = 0); an unknown input biases its estimate"]


# --------------------------------------------------------------------- single_delay
def _single_delay(plant: Plant, section) -> Derivation:
    who = "single_delay"
    p, n = plant.p, plant.n
    out_state = {i: (j, c) for j, (i, c) in output_matrix(plant, who)[1].items()}
    for i in range(p):
        if i not in out_state:
            where = plant.where("h", i)
            raise ConfigError(where, f"{who} needs outputs that are states (y_i = c x_j, the "
                              f"measured part xi2 of eq. 2): {where} is {plant.h[i]}")
    M = [out_state[i][0] for i in range(p)]
    scale = [out_state[i][1] for i in range(p)]
    U = [j for j in range(n) if j not in M]
    if not U:
        raise ConfigError("plant.h", f"{who} estimates the unmeasured states: every state is "
                          "measured here")
    lf = linear_form(plant, who)
    A1 = lf.A[np.ix_(U, U)]
    A2 = np.diag(scale) @ lf.A[np.ix_(M, U)]
    _observable(A1, A2, who + " ((A1, A2) of eq. 2)")
    ren = lf.output_names(plant)
    ys = [sympy.Symbol(f"y{i}", real=True) for i in range(p)]

    def known(i: int) -> sympy.Expr:
        """Row i of f without its unmeasured-state part: measured states, inputs, R."""
        e = lf.R[i]
        for j in M:
            if lf.A[i, j]:
                e += sympy.Float(lf.A[i, j]) * plant.x[j]
        for j, s in enumerate(plant.u):
            if lf.B[i, j]:
                e += sympy.Float(lf.B[i, j]) * s
        return e.xreplace(ren)

    F1 = [known(i) for i in U]
    # the plant's own term G of the measured states (the observer adds the k y of eq. 2)
    F2 = [known(j) if c == 1.0 else sympy.Float(c) * known(j) for j, c in zip(M, scale)]
    P = np.zeros((n, n))
    for a, j in enumerate(U):
        P[j, a] = 1.0
    for r, j in enumerate(M):
        P[j, len(U) + r] = 1.0 / scale[r]
    notes = _nominal_note(plant, who)
    K = []
    for name, F in (("lipschitz_K1", F1), ("lipschitz_K2", F2)):
        b = lipschitz_bound(F, ys)
        if b is None:
            notes.append(f"{name} = 0 (not checked): {'F1' if name.endswith('1') else 'F2'} is not "
                         "globally Lipschitz in y (interval arithmetic over all y, u)")
        K.append(0.0 if b is None else b)
    params = dict(n_unmeasured=len(U), n_outputs=p, n_inputs=plant.m, A1=_flat(A1), A2=_flat(A2),
                  F1=[to_text(e) for e in F1], F2=[to_text(e) for e in F2],
                  lipschitz_K1=K[0], lipschitz_K2=K[1], state_map=_flat(P),
                  state_names=list(plant.states))
    figures = {"xi1 (unmeasured)": ", ".join(plant.states[j] for j in U),
               "xi2 (measured)": ", ".join(f"{plant.states[j]}" + ("" if c == 1.0 else f" x {c:g}")
                                           for j, c in zip(M, scale))}
    return Derivation(params, figures, notes)


# ------------------------------------------------------------------- prescribed_time
def _prescribed_time(plant: Plant, section) -> Derivation:
    who = "prescribed_time"
    if plant.p != 1:
        raise ConfigError("plant.h", f"{who} needs one output (a SISO plant), got {plant.p}")
    if plant.m > 1:
        raise ConfigError("plant.inputs", f"{who} needs at most one known input (a SISO plant), "
                          f"got {plant.m}")
    lf = linear_form(plant, who)
    if plant.m and not np.any(lf.B):
        raise ConfigError("plant.f", f"{who} needs the input to enter linearly (b u of eq. 1-5): "
                          f"{plant.inputs[0]} enters only through {_input_terms(lf, plant)}")
    cf = canonical_form(lf.A, lf.B, lf.C)
    if cf is None:
        raise ConfigError("plant.h", f"{who}: (A, C) is not observable, so no observer canonical "
                          "form exists")
    F: list[str] = []
    if any(e != 0 for e in lf.R):
        ren = lf.output_names(plant)
        rows = []
        for i in range(plant.n):
            e = sum((sympy.Float(float(cf.T_exact[i, j])) * lf.R[j].xreplace(ren)
                     for j in range(plant.n) if cf.T_exact[i, j] != 0 and lf.R[j] != 0),
                    sympy.Integer(0))
            rows.append(to_text(e))
        F = rows
    S = np.array(cf.T_exact.inv().evalf(20).tolist(), dtype=float)
    params = dict(n_states=plant.n, relative_degree=cf.r, n_inputs=plant.m, a=cf.a, b=cf.b,
                  F=F, state_map=_flat(S), state_names=list(plant.states))
    figures = {"canonical coordinates": "x_c = T x, T from the observability matrices "
                                        "(T = O_c^-1 O)",
               "cond(T)": f"{cf.cond:.4g}", "relative degree": str(cf.r)}
    return Derivation(params, figures, _nominal_note(plant, who))


def _input_terms(lf: LinearForm, plant: Plant) -> str:
    """The remainder terms that carry the input, for a refusal."""
    return ", ".join(str(e) for e in lf.R if e.free_symbols & set(plant.u)) or "nothing"


# --------------------------------------------------------------------- hosm, luenberger
def _linear(plant: Plant, who: str, identify: bool) -> Derivation:
    if identify:
        if not plant.q:
            raise ConfigError("plant.unknown_inputs", f"{who} identifies unknown inputs, and the "
                              "plant has none (use luenberger or ekf)")
        if plant.q != plant.p:
            raise ConfigError("plant.unknown_inputs", f"{who} needs as many unknown inputs as "
                              f"outputs ({plant.p}), got {plant.q}")
    lf = linear_form(plant, who, unknown_inputs=identify)
    if not identify:
        _observable(lf.A, lf.C, who)
    F = lf.terms(plant) if any(e != 0 for e in lf.R) else []
    params = dict(n_states=plant.n, n_outputs=plant.p, n_inputs=plant.m, A=_flat(lf.A),
                  B=_flat(lf.B) if plant.m else [], C=_flat(lf.C), F=F,
                  state_names=list(plant.states))
    figures = {"open-loop eigenvalues": _complex_list(np.linalg.eigvals(lf.A))}
    if identify:
        params.update(D=_flat(lf.D), unknown_input_names=list(plant.unknown_inputs))
        figures.update(_unknown_input_structure(lf))
    return Derivation(params, figures, notes=[] if identify else _nominal_note(plant, who))


def _observable(A: np.ndarray, C: np.ndarray, who: str) -> None:
    rank = observability_rank(A, C)
    if rank < A.shape[0]:
        raise ConfigError("plant.h", f"{who} needs the linear part observable from h: (A, C) "
                          f"has PBH rank {rank} < {A.shape[0]} at an eigenvalue of A")


def _complex_list(z) -> str:
    return ", ".join(f"{v.real:.4g}" if abs(v.imag) < 1e-9 * max(1.0, abs(v)) else
                     f"{v.real:.4g}{v.imag:+.4g}j" for v in np.sort_complex(np.asarray(z, complex)))


def _unknown_input_structure(lf: LinearForm) -> dict[str, str]:
    """Fridman-Levant-Davila's conditions on (A, C, D): the relative degree exists and the
    invariant zeros are stable (strongly detectable; none: strongly observable)."""
    try:
        r, _ = relative_degree(lf.A, lf.C, lf.D)
    except StructureError as exc:
        raise ConfigError("plant.unknown_inputs", f"hosm: {exc}") from None
    zeros = invariant_zeros(lf.A, lf.C, lf.D)
    if np.any(zeros.real >= 0):
        raise ConfigError("plant.unknown_inputs", "hosm needs a strongly detectable plant "
                          "(every invariant zero with Re < 0); the zeros of (A, D, C) are "
                          + _complex_list(zeros))
    return {"relative degree": ", ".join(map(str, r)),
            "invariant zeros": _complex_list(zeros) or "none",
            "unknown input": "strongly observable (exact in finite time)" if not len(zeros)
            else "strongly detectable (the zero dynamics converge at the zeros' rates)"}


# ----------------------------------------------------------------- models as text
def _as_text(plant: Plant, who: str, single_output: bool) -> Derivation:
    if single_output and plant.p != 1:
        raise ConfigError("plant.h", f"{who} needs one output (the paper's single-output "
                          f"setting), got {plant.p}")
    f = [to_text(e) for e in plant.nominal(plant.f_raw)] if plant.q else list(plant.f_texts)
    params = dict(states=list(plant.states), inputs=list(plant.inputs),
                  constants=list(plant.constant_texts), f=f, h=list(plant.h_texts))
    return Derivation(params, notes=_nominal_note(plant, who))


# ----------------------------------------------------------------- observability form
def _chain(plant: Plant, who: str) -> Derivation:
    if not 2 <= plant.n <= 6:
        raise ConfigError("plant.states", f"{who} takes 2 to 6 states, got {plant.n}")
    cf = chain_form(plant, who)
    params = dict(n_states=plant.n, n_inputs=plant.m, f=cf.f_n, state_names=list(plant.states),
                  chain_map=[] if cf.identity else _flat(cf.T))
    figures = {"observability form": "the plant itself (x0' = x1, ..., y = x0)" if cf.identity
               else "z = T x, T = d(h, h', ...)/dx = " + np.array2string(cf.T, precision=6)}
    return Derivation(params, figures, _nominal_note(plant, who))


# ----------------------------------------------------------------- model-free
def _joint_kalman(plant: Plant, section) -> Derivation:
    """The outputs only: each must be a state (an encoder's position); the chain's states
    are named after it and the states its f says are its derivatives."""
    who = "joint_kalman"
    _, measured = output_matrix(plant, who)
    by_output = {i: (j, c) for j, (i, c) in measured.items()}
    order = section.get("order", 3)
    order = order if isinstance(order, int) and 2 <= order <= 4 else 3
    names: list[str] = []
    for i in range(plant.p):
        if i not in by_output or by_output[i][1] != 1.0:
            where = plant.where("h", i)
            raise ConfigError(where, f"{who} needs each output to be a state (an encoder's "
                              f"position, y = q): {where} is {plant.h[i]}")
        j = by_output[i][0]
        chain = [plant.states[j]]
        for k in range(1, order):
            nxt = plant.f[j] if j is not None else None
            j = plant.x.index(nxt) if nxt is not None and nxt in plant.x else None
            chain.append(plant.states[j] if j is not None else
                         chain[0] + ("_dot", "_ddot", "_dddot")[k - 1])
        names += chain
    notes = [f"{who} is model-free: it takes the measured outputs from the plant (h) and "
             "nothing of f, the inputs or the constants"]
    return Derivation(dict(n_outputs=plant.p, state_names=names),
                      {"chain per output": ", ".join(names)}, notes)


_DERIVATIONS: dict[str, Callable[[Plant, Mapping[str, Any]], Derivation]] = {
    "single_delay": _single_delay,
    "prescribed_time": _prescribed_time,
    "hosm": lambda plant, section: _linear(plant, "hosm", True),
    "luenberger": lambda plant, section: _linear(plant, "luenberger", False),
    "newton_inversion": lambda plant, section: _as_text(plant, "newton_inversion", True),
    "ekf": lambda plant, section: _as_text(plant, "ekf", False),
    "global_norm": lambda plant, section: _chain(plant, "global_norm"),
    "high_gain": lambda plant, section: _chain(plant, "high_gain"),
    "joint_kalman": _joint_kalman,
}


def derive(type_name: str, plant: Plant, section: Mapping[str, Any]) -> Derivation:
    """The explicit parameters of observer ``type_name`` for ``plant`` (see the module doc)."""
    fn = _DERIVATIONS.get(type_name)
    if fn is None:
        raise ConfigError("observer.type", f"no derivation from the plant block for {type_name!r}")
    return fn(plant, section)
