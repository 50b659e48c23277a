"""The seam between an observer family and the compiled block loop: the kernel protocol.

An observer family is a **kernel**, pure per-sample code over flat float64 arrays, plus an
**adapter** class (observers/base.py ``KernelObserver``) that owns what runs once: the
parameters, the design, the derivation, the restart values.  The kernel is ONE function
with the signature core/jit.py ``KERNEL``, called through a function pointer so that one
compiled loop serves every family (and is cached on disk):

    kernel(op, st, nx, c, ic, wk, a, b, y, u, models) -> 0, or a rejection code

- ``op = RESTART``: forget the run; the next sample starts a new one from the initial
  estimate ``y`` (plant coordinates) when ``a > 0``, else from the family's default;
  writes ``st`` directly;
- ``op = FIRST``: the first sample (y, u) after a restart (model time 0); ``a`` is the time
  since the last sample before the restart (< 0: none), for warm restarts;
- ``op = STEP``: advance by ``b`` (> 0, a whole number of 1 us, at most the family's max
  step) to model time ``a`` since the start and take the sample (y, u);
- ``op = ADVANCE`` (families with ``ic[HAS_ADVANCE]``): integrate to model time ``a`` with
  a new input u (observers that predict between sparse measurements); y is empty.

``st`` is the committed state, ``nx`` the candidate the kernel writes (it starts as a copy
of st); 0 commits nx, a rejection code (core/reasons.py) leaves st as it was: a rejected
sample leaves no trace.  ``c``/``ic`` are the constants the adapter built (floats /
integers), ``wk`` the family's work memory (step caches, scratch, delay buffers written past
the committed end: nothing in wk is state a rejection must undo), ``models`` the model
terms (core/model_code.py) in slots the family documents.  No dicts, exceptions or Python
objects; allocation only where a step size is met for the first time.

What the runner reads off a state, at fixed places:

    st[RESIDUAL]    output residual of the last sample (nan before one)
    st[HEALTH]      the family's health figure (published on ~/convergence)
    st[CONVERGED]   -1: the runner's rule, else 0/1 (a family that knows better)
    st[GUARANTEED]  guaranteed convergence time after a restart (inf: none)
    st[ic[EST] : ic[EST] + ic[N_STATES]]          the estimate, plant coordinates
    st[ic[UI] : ic[UI] + ic[N_UI]]                the unknown-input estimate (N_UI = 0: none)
    st[ic[EXTRA] : ic[EXTRA] + ic[N_EXTRA]]       the family's extra convergence values

and ``c[MAX_STEP]`` is the longest interval the family bridges with bounded work.

The observer's clock (whole 1 us quanta since the first sample after a restart) is kept
here too, in ``clk = [t0 (nan: waiting for a first sample), k, t_last]``: ``update`` below is
the only place that turns stamps into the (s, h) a family sees, for the adapter's own
``update`` and for the runner's block loop alike.

ROS-free.
"""
from __future__ import annotations

import math

import numpy as np

from ..core import jit as J
from ..core.jit import jit
from ..core.reasons import CODE

# -- state header --------------------------------------------------------------------
RESIDUAL, HEALTH, CONVERGED, GUARANTEED = 0, 1, 2, 3
HEADER = 4
# -- integer constants header ----------------------------------------------------------
N_STATES, EST, N_UI, UI, N_EXTRA, EXTRA, HAS_ADVANCE = 0, 1, 2, 3, 4, 5, 6
IC_HEADER = 8
# -- float constants header -----------------------------------------------------------
MAX_STEP = 0
C_HEADER = 1
# -- the clock ------------------------------------------------------------------------
CLK_T0, CLK_K, CLK_T_LAST = 0, 1, 2
CLOCK_SIZE = 3

#: model time runs on this grid (s): see core/discretize.py
STEP_QUANTUM = 1e-6
_TOO_CLOSE = CODE["stamp_too_close"]
_TOO_LONG = CODE["step_too_long"]


@jit
def quanta(dt):
    """dt (s) as a whole number of STEP_QUANTUM (Python's round: half to even)."""
    return round(dt / STEP_QUANTUM)


def _restart(kernels, models, st, nx, c, ic, wk, clk, x0, has_x0):
    """Restart at the next sample (the clock waits for it; t_last is kept)."""
    clk[CLK_T0] = math.nan
    clk[CLK_K] = 0.0
    return kernels[0](J.RESTART, st, nx, c, ic, wk, 1.0 if has_x0 else 0.0, 0.0, x0, x0, models)


def _update(kernels, models, st, nx, c, ic, wk, clk, t, y, u):
    """Take the sample (t, y, u): the clock's step, then FIRST or STEP, committed when the
    kernel returns 0.  Returns 0 or the rejection code (state and clock unchanged)."""
    kernel = kernels[0]
    if clk[CLK_T0] != clk[CLK_T0]:                     # waiting for a first sample
        gap = -1.0 if clk[CLK_T_LAST] != clk[CLK_T_LAST] else \
            quanta(t - clk[CLK_T_LAST]) * STEP_QUANTUM
        nx[:] = st
        code = kernel(J.FIRST, st, nx, c, ic, wk, gap, 0.0, y, u, models)
        if code != 0:
            return code
        st[:] = nx
        clk[CLK_T0] = t
        clk[CLK_K] = 0.0
        clk[CLK_T_LAST] = t
        return 0
    k = quanta(t - clk[CLK_T0])
    if k <= clk[CLK_K]:
        return _TOO_CLOSE
    h = (k - clk[CLK_K]) * STEP_QUANTUM
    if h > c[MAX_STEP]:
        return _TOO_LONG
    nx[:] = st
    code = kernel(J.STEP, st, nx, c, ic, wk, k * STEP_QUANTUM, h, y, u, models)
    if code != 0:
        return code
    st[:] = nx
    clk[CLK_K] = k
    clk[CLK_T_LAST] = t
    return 0


def _advance(kernels, models, st, nx, c, ic, wk, clk, t, u, y_empty):
    """Integrate to t with the new input u (families with ic[HAS_ADVANCE]), committed when
    the kernel returns 0; a no-op before the first sample of a run."""
    if ic[HAS_ADVANCE] == 0 or clk[CLK_T0] != clk[CLK_T0]:
        return 0
    s = quanta(t - clk[CLK_T0]) * STEP_QUANTUM
    nx[:] = st
    code = kernels[0](J.ADVANCE, st, nx, c, ic, wk, s, 0.0, y_empty, u, models)
    if code == 0:
        st[:] = nx
    return code


# compiled at their first call, for the kernel and model lists they get (typed lists of
# function pointers: one compilation serves every family, and is cached on disk)
restart, update, advance = jit(_restart), jit(_update), jit(_advance)


def layout_ic(n_states: int, est: int, n_ui: int = 0, ui: int = 0, n_extra: int = 0,
              extra: int = 0, has_advance: bool = False, extra_ints=()) -> np.ndarray:
    """The integer constants header (and a family's own integers after it)."""
    head = [n_states, est, n_ui, ui, n_extra, extra, int(has_advance), 0]
    return np.array(head + list(extra_ints), dtype=np.int64)
