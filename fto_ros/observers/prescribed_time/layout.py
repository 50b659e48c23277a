"""The memory layout of the prescribed-time kernel: where each constant, state value and
scratch vector lives in the flat arrays (observers/kernel.py's protocol), and the views onto
them.  kernel.py documents the layout; the adapter builds the arrays with it.

ROS-free.
"""
from __future__ import annotations

from ...core.jit import jit
from ..kernel import C_HEADER, HEADER, IC_HEADER

# -- integer constants ------------------------------------------------------------------
(N, NIN, HAS_F, MODE, HAS_GEND, HAS_SMAP, KEEPS, FOH, W, STEPS, EBARS, AFTERS, SCRATCH,
 SLOTS, O_HG, O_C, O_CINV, O_L, O_GEND, O_AP, O_B, O_S, O_EXP) = range(IC_HEADER, IC_HEADER + 23)
MODE_RESTART, MODE_STOP, MODE_CONSTANT = 0, 1, 2
MODES = ("restart", "stop", "constant")
# -- float constants --------------------------------------------------------------------
T_, S_END, BETA, NM = range(C_HEADER, C_HEADER + 4)
C_ARRAYS = C_HEADER + 4
# -- state scalars ----------------------------------------------------------------------
(HAS_PREV, KP, YP, UP, R0, HAS_T, T_MODEL, KSTART, TW, AFTER, HAS_FROZEN, FROZEN_ID,
 RESTARTS, RESTARTS_TOTAL, HAS_END, END_T, END_REASON, G_PEAK, POST) = range(HEADER, HEADER + 19)
X_PUB = HEADER + 19
#: END_REASON: the configured end (T, t_stop or g_max), or the sampling limit
END_CONFIGURED, END_SAMPLING = 0.0, 1.0
# -- work ---------------------------------------------------------------------------------
WK_NEXT_ID, WK_AFTER_ID = 0, 1
WK_HEADER = 2
# -- the result of a step (scratch): post, r1, tw, after, restarts, has end, end t, end
#    reason, new frozen gains (0/1), whether they are set (0/1)
(RS_POST, RS_R1, RS_TW, RS_AFTER, RS_RESTARTS, RS_HAS_END, RS_END_T, RS_END_REASON, RS_NEW,
 RS_FROZEN) = range(10)
RS_SIZE = 10


def state_size(n: int) -> int:
    return X_PUB + 4 * n


def scratch_size(n: int, w: int) -> int:
    """Floats of the scratch (``scratch``): z, 13 n-vectors, scal, bases, mu^k, result."""
    return (n + 2 * w) + 13 * n + 4 * n + 4 + (n + 1) + 1 + RS_SIZE


# -- views -----------------------------------------------------------------------------
@jit
def mat(c, ic, at, rows, cols):
    """The rows x cols constant matrix at offset ic[at] of c."""
    o = ic[at]
    return c[o:o + rows * cols].reshape(rows, cols)


@jit
def cvec(c, ic, at):
    """The n-vector constant at offset ic[at] of c."""
    o = ic[at]
    return c[o:o + ic[N]]


@jit
def scratch(ic, wk, k):
    """Scratch vector k: 0 z (n + 2W), 1 xm, 2 q, 3 pa, 4 pb, 5 d, 6 t1, 7 t2, 8 g, 9 f0,
    10 f1, 11 f_next, 12 x new, 13 frozen new (n each), 14 scal (4n), 15 bases (4),
    16 mu^k (n + 1), 17 the step's result (RS_SIZE), 18 one float (a power's base)."""
    n, w = ic[N], ic[W]
    o = ic[SCRATCH]
    if k == 0:
        return wk[o:o + n + 2 * w]
    o += n + 2 * w
    if k <= 13:
        o += (k - 1) * n
        return wk[o:o + n]
    o += 13 * n
    if k == 14:
        return wk[o:o + 4 * n]
    o += 4 * n
    if k == 15:
        return wk[o:o + 4]
    o += 4
    if k == 16:
        return wk[o:o + n + 1]
    o += n + 1
    if k == 17:
        return wk[o:o + RS_SIZE]
    o += RS_SIZE
    return wk[o:o + 1]


@jit
def vec(s, ic, k):
    """State vector k: 0 x published, 1 x, 2 F of the last sample, 3 frozen gains."""
    n = ic[N]
    o = X_PUB + k * n
    return s[o:o + n]
