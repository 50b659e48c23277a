"""The seam between an observer family and the compiled block loop: the kernel protocol.

An observer family is a **kernel**, pure per-sample code over flat float64 arrays, plus an
**adapter** class (observers/base.py ``KernelObserver``) that owns what runs once: the
parameters, the design, the derivation, the restart values.  The kernel is ONE function
with the signature core/jit.py ``KERNEL``, called through a function pointer so that one
compiled loop serves every family (and is cached on disk):

    kernel(op, st, nx, c, ic, wk, a, b, y, u, models) -> 0, or a rejection code

- ``op = RESTART``: forget the run; the next sample starts a new one from the initial
  estimate ``y`` (plant coordinates) when ``a > 0``, else from the family's default;
  ``a < 0`` is a cold restart (after a fault: the estimate is not to be trusted), so a
  family that keeps its estimate over a restart (prescribed_time) forgets it too;
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

**Compositions** (an observer made of other observers: ``track``) are handled here and
nowhere else, so the runner's loop runs them as any family.  A composition is a kernel
(``kernels[0]``) whose ``ic[COMPOSED]`` points to a child table; its children are further
kernels of the list (``kernels[1:]``), and each child's arrays are sub-slices of the
composition's: its state and clock in the composition's state (so the composition's
commit commits them, and a rejected sample leaves no trace in any of them), its candidate,
work, constants and integer constants in the composition's wk / c / ic, its model terms in
the composition's model list after the composition's own MODEL_SLOTS.  The child table,
``ic[tab:]``: ``[children, request offset in wk]``, then per child ``CHILD_WIDTH`` integers
(``CH_*``: kernel index, state offset and length, clock offset, candidate offset, the
offsets and lengths of its c, ic and wk, its first model slot and model count).

A composition's kernel cannot call kernels itself (its signature has no kernel list): it
asks.  It writes a call into its request record ``wk[rq:]`` (``RQ_CHILD`` 1.., ``RQ_OP``
CALL_RESTART with ``RQ_HAS_X0`` and the estimate at ``RQ_X0``, or CALL_UPDATE: the
composition's sample (t, y, u) through the child's own clock, FIRST or STEP as for any
observer) and its own resume point ``RQ_PC``, and returns CALL; ``_run`` below runs the call
on the child's sub-slices (of the composition's candidate, or of its state at a RESTART),
with the child's model terms moved into slots 0.. of the model list, writes the child's
result code to ``RQ_RESULT`` and calls the composition again with op RESUME, until it
returns 0 or a rejection code; at most MAX_CALLS calls per sample.  Compositions have no
ADVANCE, and a child is not itself a composition.

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
N_STATES, EST, N_UI, UI, N_EXTRA, EXTRA, HAS_ADVANCE, COMPOSED = 0, 1, 2, 3, 4, 5, 6, 7
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

# -- compositions (see the module doc) --------------------------------------------------
#: op: a composition's kernel resumed after the call it asked for
RESUME = 4
#: what a composition's kernel returns to have the call in its request record run
CALL = -1
#: the child table at ic[ic[COMPOSED]]: its header, then one row per child
TAB_CHILDREN, TAB_REQUEST = 0, 1
TAB_HEADER = 2
(CH_KERNEL, CH_ST, CH_ST_LEN, CH_CLK, CH_NX, CH_C, CH_C_LEN, CH_IC, CH_IC_LEN, CH_WK, CH_WK_LEN,
 CH_MODELS, CH_N_MODELS) = range(13)
CHILD_WIDTH = 13
#: the request record in wk: the composition's own resume point, then the call
RQ_PC, RQ_CHILD, RQ_OP, RQ_HAS_X0, RQ_RESULT, RQ_X0 = range(6)
CALL_RESTART, CALL_UPDATE = 0, 1
#: calls one composition's kernel may ask for per sample (a bound on the work, and a guard)
MAX_CALLS = 16
#: a composition that asked for more calls than MAX_CALLS or for a child it has not, or
#: was resumed at no phase of its own (a bug)
BROKEN = CODE["observer_error"]


@jit
def quanta(dt):
    """dt (s) as a whole number of STEP_QUANTUM (Python's round: half to even)."""
    return round(dt / STEP_QUANTUM)


@jit
def _begin(clk, c, t):
    """The clock's verdict on a sample at t: (0, FIRST, gap, 0, 0) while waiting for a first
    sample (gap: since the last sample before the restart, < 0: none), (0, STEP, s, h, k)
    for a step of h to model time s = k quanta, or (rejection code, ...)."""
    if clk[CLK_T0] != clk[CLK_T0]:                     # waiting for a first sample
        gap = -1.0 if clk[CLK_T_LAST] != clk[CLK_T_LAST] else \
            quanta(t - clk[CLK_T_LAST]) * STEP_QUANTUM
        return 0, J.FIRST, gap, 0.0, 0.0
    k = float(quanta(t - clk[CLK_T0]))
    if k <= clk[CLK_K]:
        return _TOO_CLOSE, J.STEP, 0.0, 0.0, k
    h = (k - clk[CLK_K]) * STEP_QUANTUM
    if h > c[MAX_STEP]:
        return _TOO_LONG, J.STEP, 0.0, 0.0, k
    return 0, J.STEP, k * STEP_QUANTUM, h, k


@jit
def _commit(clk, op, t, k):
    """The clock after the sample at t was taken (op FIRST or STEP, k its quanta)."""
    if op == J.FIRST:
        clk[CLK_T0] = t
        clk[CLK_K] = 0.0
    else:
        clk[CLK_K] = k
    clk[CLK_T_LAST] = t


@jit
def _child(kernels, models, home, c, ic, wk, e, rq, t, y, u):
    """Run the call in the request record wk[rq:] on the child described at ic[e:] (its
    state and clock in ``home``, the composition's candidate or, at a restart, its state)."""
    s0, sn = ic[e + CH_ST], ic[e + CH_ST_LEN]
    st = home[s0:s0 + sn]
    clk = home[ic[e + CH_CLK]:ic[e + CH_CLK] + CLOCK_SIZE]
    nx = wk[ic[e + CH_NX]:ic[e + CH_NX] + sn]
    cc = c[ic[e + CH_C]:ic[e + CH_C] + ic[e + CH_C_LEN]]
    ci = ic[ic[e + CH_IC]:ic[e + CH_IC] + ic[e + CH_IC_LEN]]
    cw = wk[ic[e + CH_WK]:ic[e + CH_WK] + ic[e + CH_WK_LEN]]
    mo = ic[e + CH_MODELS]
    for j in range(ic[e + CH_N_MODELS]):            # the child's model slots first
        models[j] = models[mo + j]
    kernel = kernels[ic[e + CH_KERNEL]]
    if wk[rq + RQ_OP] == CALL_RESTART:
        clk[CLK_T0] = math.nan
        clk[CLK_K] = 0.0
        x0 = wk[rq + RQ_X0:rq + RQ_X0 + ci[N_STATES]]
        return kernel(J.RESTART, st, nx, cc, ci, cw, wk[rq + RQ_HAS_X0], 0.0, x0, x0, models)
    code, op, a, b, k = _begin(clk, cc, t)
    if code != 0:
        return code
    nx[:] = st
    code = kernel(op, st, nx, cc, ci, cw, a, b, y, u, models)
    if code == 0:
        st[:] = nx
        _commit(clk, op, t, k)
    return code


@jit
def _run(kernels, models, op, st, nx, c, ic, wk, a, b, y, u, t):
    """kernels[0] for op; a composition's kernel with the calls to its children it asks for
    (it returns CALL, is resumed with op RESUME, until it returns 0 or a rejection)."""
    code = kernels[0](op, st, nx, c, ic, wk, a, b, y, u, models)
    tab = ic[COMPOSED]
    if tab == 0:
        return code
    home = st if op == J.RESTART else nx
    rq = ic[tab + TAB_REQUEST]
    calls = 0
    while code == CALL:
        calls += 1
        child = int(wk[rq + RQ_CHILD])
        if calls > MAX_CALLS or not 1 <= child <= ic[tab + TAB_CHILDREN]:
            return BROKEN
        e = tab + TAB_HEADER + (child - 1) * CHILD_WIDTH
        wk[rq + RQ_RESULT] = _child(kernels, models, home, c, ic, wk, e, rq, t, y, u)
        code = kernels[0](RESUME, st, nx, c, ic, wk, a, b, y, u, models)
    return code


def _restart(kernels, models, st, nx, c, ic, wk, clk, x0, has_x0, cold):
    """Restart at the next sample (the clock waits for it; t_last is kept); ``cold``: after
    a fault, nothing of the old estimate is kept (op RESTART with a < 0)."""
    clk[CLK_T0] = math.nan
    clk[CLK_K] = 0.0
    a = 1.0 if has_x0 else (-1.0 if cold else 0.0)
    return _run(kernels, models, J.RESTART, st, nx, c, ic, wk, a, 0.0, x0, x0, math.nan)


def _update(kernels, models, st, nx, c, ic, wk, clk, t, y, u):
    """Take the sample (t, y, u): the clock's step, then FIRST or STEP, committed when the
    kernel returns 0.  Returns 0 or the rejection code (state and clock unchanged)."""
    code, op, a, b, k = _begin(clk, c, t)
    if code != 0:
        return code
    nx[:] = st
    code = _run(kernels, models, op, st, nx, c, ic, wk, a, b, y, u, t)
    if code != 0:
        return code
    st[:] = nx
    _commit(clk, op, t, k)
    return 0


def _advance(kernels, models, st, nx, c, ic, wk, clk, t, u, y_empty):
    """Integrate to t with the new input u (families with ic[HAS_ADVANCE]; compositions have
    none), committed when the kernel returns 0; a no-op before the first sample of a run."""
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
