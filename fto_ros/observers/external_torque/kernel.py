"""Per-sample kernel of the windowed momentum estimator of an arm's external torques
(protocol: observers/kernel.py; the derivation: docs/external_torque.md).

Per sample (y = the joints' positions q, u = [effort (n), passive joints' positions (k)]):

- the robust exact differentiator (core/differentiator_step.py, order 2) gives the velocity
  published with q (x = [q, v]) and used provisionally for the newest samples' terms;
- the sample goes into the ring with its model terms (arm/dynamics.py's momentum_terms on
  the tree's packed rows in the constants: M, M q, Mdot, Mdot q, phi = C^T v - g - f_c
  tanh(v / w)) and its torque (the effort as ``effort.meaning`` says: times kt * gear for a
  current, plus g(q) for a command without gravity);
- the sample m before the newest gets its centred velocity (the least-squares slope of the
  2 m + 1 positions around it, on their actual stamps) and its velocity terms again; the
  first m samples of a run get the slope of the first 2 m + 1 (no cold-start velocity stays
  in the window);
- once the ring holds W + 1 samples: the weights of arm/window.py on the samples' actual
  ages and the window's sum give tau_ext (the unknown input), exact T after any change;
- the detector (arm/detect.py) on tau_ext over its noise scale ||A|| ||M_i,:(q)||.

A step longer than the nominal period (lost messages) is bridged: the torque stays held
across it (the gap rule bounds what that adds; longer steps are the runner's restarts, at
c[MAX_STEP]). The layout of c, ic, the state and the work memory is the adapter's
(observers/external_torque/adapter.py, ``Layout``): offsets in ic after the header.
"""
from __future__ import annotations

import math

from ...arm import detect as DT
from ...arm import dynamics as dyn
from ...arm import window as WN
from ...arm.tree import COL
from ...core import differentiator_step as RED
from ...core import jit as J
from ...core.jit import jit
from ...core.reasons import CODE
from ..kernel import CONVERGED, GUARANTEED, HEALTH, IC_HEADER, RESIDUAL

(I_N, I_K, I_NB, I_W, I_M, I_MEANING, I_ROWS, I_B, I_FC, I_TF, I_RED, I_DET, I_SC, I_SRED,
 I_RING, I_SDET, I_SLOT, I_WRED, I_WU, I_WA, I_WB, I_WC, I_WD, I_WT, I_WQ, I_WV, I_WG,
 I_WT5, I_WQ5, I_WE, I_EST, I_UI, I_EXTRA) = range(IC_HEADER, IC_HEADER + 33)
# -- float constants after the header (c[0] is MAX_STEP) --------------------------------------
C_WIDTH, C_PERIOD = 1, 2
# -- state scalars at ic[I_SC] --------------------------------------------------------------
COUNT, HEAD, BRIDGED, MAX_BRIDGED, GAIN, VALID = range(6)
N_SCALARS = 6
NO_GRAVITY, MEASURED = 1, 2
#: effort.meaning -> the code in ic[I_MEANING]
MEANINGS_CODE = {"commanded": 0, "commanded_no_gravity": NO_GRAVITY, "measured": MEASURED,
                 "current": 3}
_NON_FINITE_TERM = CODE["non_finite_model_term"]
_NON_FINITE = CODE["non_finite_estimate"]
_NON_FINITE_DIFF = CODE["non_finite_differentiator"]


@jit
def slot_offsets(n, k):
    """(q, v, passive, effort, M, M q, Mdot, Mdot q, phi, tau) offsets in a ring slot (its
    stamp at 0) and the slot's width."""
    oq = 1
    ov = oq + n
    op = ov + n
    oe = op + k
    om = oe + n
    omq = om + n * n
    omd = omq + n
    omdq = omd + n * n
    ophi = omdq + n
    otau = ophi + n
    return oq, ov, op, oe, om, omq, omd, omdq, ophi, otau, otau + n


@jit
def _slot(st, ic, j):
    """Ring position of the sample j steps before the newest."""
    W1 = ic[I_W] + 1
    sc = ic[I_SC]
    return ic[I_RING] + ((int(st[sc + HEAD]) - j) % W1) * ic[I_SLOT]


@jit
def _terms(st, c, ic, base, with_mass):
    """The model terms of the ring sample at ``base`` from its q, v and passive positions;
    0, or 1 when one is not finite."""
    n, k = ic[I_N], ic[I_K]
    oq, ov, op, oe, om, omq, omd, omdq, ophi, otau, width = slot_offsets(n, k)
    rows = c[ic[I_ROWS]:ic[I_ROWS] + ic[I_NB] * 32].reshape(ic[I_NB], COL)
    q = st[base + oq:base + oq + n]
    v = st[base + ov:base + ov + n]
    pas = st[base + op:base + op + k]
    out = dyn.momentum_terms(rows, n, q, pas, v, with_mass)
    o = 2 * n * n
    for i in range(n):
        if with_mass:
            smq = 0.0
            for j in range(n):
                st[base + om + i * n + j] = out[i * n + j]
                smq += out[i * n + j] * q[j]
            st[base + omq + i] = smq
        smd = 0.0
        for j in range(n):
            st[base + omd + i * n + j] = out[n * n + i * n + j]
            smd += out[n * n + i * n + j] * q[j]
        st[base + omdq + i] = smd
        fc = c[ic[I_FC] + i]
        st[base + ophi + i] = out[o + i] - out[o + n + i] - fc * math.tanh(v[i] / c[C_WIDTH])
        tau = st[base + oe + i] * c[ic[I_TF] + i]
        if ic[I_MEANING] == NO_GRAVITY:
            tau += out[o + n + i]
        st[base + otau + i] = tau
    acc = 0.0
    for x in out:
        acc += x * 0.0
    return 0 if acc == 0.0 else 1


@jit
def _centre(st, c, ic, wk, newest, first, count, targets_from, targets_to):
    """Give the run samples targets_from..targets_to - 1 the slope of the run samples
    first..first + count - 1 (run indices; ``newest`` is the newest's) and their terms."""
    n, k = ic[I_N], ic[I_K]
    oq, ov = 1, 1 + n
    tq = wk[ic[I_WT]:ic[I_WT] + count]
    qq = wk[ic[I_WQ]:ic[I_WQ] + count * n].reshape(count, n)
    for l in range(count):
        b = _slot(st, ic, newest - (first + l))
        tq[l] = st[b]
        for i in range(n):
            qq[l, i] = st[b + oq + i]
    v = wk[ic[I_WV]:ic[I_WV] + n]
    WN.slope(tq, qq, 0, count, n, v)
    for r in range(targets_from, targets_to):
        b = _slot(st, ic, newest - r)
        for i in range(n):
            st[b + ov + i] = v[i]
        if _terms(st, c, ic, b, False) != 0:
            return 1
    return 0


@jit
def _estimate(st, c, ic, wk):
    """tau_ext from the full ring into the state's UI; ||A|| into GAIN. 0 or a code."""
    n, k, W = ic[I_N], ic[I_K], ic[I_W]
    oq, ov, op, oe, om, omq, omd, omdq, ophi, otau, width = slot_offsets(n, k)
    u = wk[ic[I_WU]:ic[I_WU] + W + 1]
    A = wk[ic[I_WA]:ic[I_WA] + W + 1]
    B = wk[ic[I_WB]:ic[I_WB] + W + 1]
    C = wk[ic[I_WC]:ic[I_WC] + W + 1]
    D = wk[ic[I_WD]:ic[I_WD] + W]
    b0 = _slot(st, ic, 0)
    s0 = st[b0]
    for j in range(W + 1):
        u[j] = s0 - st[_slot(st, ic, j)]
    gain = WN.weights(u, W, A, B, C, D)
    est = st[ic[I_UI]:ic[I_UI] + n]
    for i in range(n):
        est[i] = 0.0
    for j in range(W + 1):
        bj = _slot(st, ic, j)
        for i in range(n):
            mq = 0.0
            mdq = 0.0
            for l in range(n):
                qc = st[b0 + oq + l]
                mq += st[bj + om + i * n + l] * qc
                mdq += st[bj + omd + i * n + l] * qc
            qt = st[bj + oq + i] - st[b0 + oq + i]
            e = A[j] * (st[bj + omq + i] - mq) - B[j] * (st[bj + omdq + i] - mdq) \
                + c[ic[I_B] + i] * B[j] * qt - C[j] * st[bj + ophi + i]
            if j >= 1:
                e -= D[j - 1] * st[bj + otau + i]
            est[i] += e
    st[ic[I_SC] + GAIN] = gain
    acc = 0.0
    for i in range(n):
        acc += est[i] * 0.0
    return 0 if acc == 0.0 and gain == gain else _NON_FINITE


@jit
def _scale(st, ic, wk):
    """Per joint, the estimate's noise scale ||A|| ||M_i,:(q)||_2 (Nm per rad), in wk."""
    n, k = ic[I_N], ic[I_K]
    om = slot_offsets(n, k)[4]
    b0 = _slot(st, ic, 0)
    g = wk[ic[I_WG]:ic[I_WG] + n]
    gain = st[ic[I_SC] + GAIN]
    for i in range(n):
        acc = 0.0
        for l in range(n):
            x = st[b0 + om + i * n + l]
            acc += x * x
        g[i] = gain * math.sqrt(acc)
    return g


@jit
def _encoder(st, c, ic, wk):
    """The encoder-noise residual of the five newest samples, to the detector."""
    n = ic[I_N]
    t5 = wk[ic[I_WT5]:ic[I_WT5] + 5]
    q5 = wk[ic[I_WQ5]:ic[I_WQ5] + 5 * n].reshape(5, n)
    for l in range(5):
        b = _slot(st, ic, 4 - l)
        t5[l] = st[b]
        for i in range(n):
            q5[l, i] = st[b + 1 + i]
    e = wk[ic[I_WE]:ic[I_WE] + n]
    WN.extrapolation_residual(t5, q5, n, e)
    DT.encoder_sample(st, ic[I_SDET], c, ic[I_DET], n, e)


@jit
def _publish(st, ic, q):
    """x = [q, the differentiator's velocity]; the output residual: its innovation."""
    n = ic[I_N]
    NT = 3
    so = ic[I_SRED]
    acc = 0.0
    for i in range(n):
        st[ic[I_EST] + i] = q[i]
        st[ic[I_EST] + n + i] = st[so + i * (2 * NT + 1) + NT + 1]
        d = st[so + i * (2 * NT + 1) + 2 * NT] - st[so + i * (2 * NT + 1)]
        acc += d * d
    st[RESIDUAL] = math.sqrt(acc)


@jit
def _push(st, c, ic, s, q, u):
    """The sample (model time s) into the newest ring slot with its terms at the
    differentiator's velocity; 0 or a code."""
    n, k = ic[I_N], ic[I_K]
    oq, ov, op, oe = 1, 1 + n, 1 + 2 * n, 1 + 2 * n + k
    b = _slot(st, ic, 0)
    st[b] = s
    NT = 3
    so = ic[I_SRED]
    for i in range(n):
        st[b + oq + i] = q[i]
        st[b + ov + i] = st[so + i * (2 * NT + 1) + NT + 1]
        st[b + oe + i] = u[i]
    for i in range(k):
        st[b + op + i] = u[n + i]
    return _NON_FINITE_TERM if _terms(st, c, ic, b, True) != 0 else 0


@jit
def _restart(st, c, ic):
    sc = ic[I_SC]
    st[sc + COUNT] = 0.0
    st[sc + HEAD] = 0.0
    st[sc + VALID] = 0.0
    st[RESIDUAL] = math.nan
    st[CONVERGED] = 0.0
    st[GUARANTEED] = ic[I_W] * c[C_PERIOD]
    n = ic[I_N]
    for i in range(n):
        st[ic[I_UI] + i] = 0.0
    DT.restarted(st, ic[I_SDET], n)
    DT.write_extras(st, ic[I_SDET], n, 0.0, st, ic[I_EXTRA])
    return 0


@jit
def _first(nx, c, ic, wk, y, u):
    n = ic[I_N]
    RED.reset(c, ic[I_RED], nx, ic[I_SRED], y, y, False)
    sc = ic[I_SC]
    nx[sc + COUNT] = 1.0
    nx[sc + HEAD] = 0.0
    code = _push(nx, c, ic, 0.0, y, u)
    if code != 0:
        return code
    _publish(nx, ic, y)
    DT.write_extras(nx, ic[I_SDET], n, 0.0, nx, ic[I_EXTRA])
    return 0


@jit
def _step(st, nx, c, ic, wk, s, h, y, u):
    n, W, m = ic[I_N], ic[I_W], ic[I_M]
    sc = ic[I_SC]
    if RED.update(c, ic[I_RED], st, ic[I_SRED], nx, ic[I_SRED], h, y, wk, ic[I_WRED]) != 0:
        return _NON_FINITE_DIFF
    count = int(nx[sc + COUNT]) + 1
    nx[sc + COUNT] = count
    nx[sc + HEAD] = (int(nx[sc + HEAD]) + 1) % (W + 1)
    if h > 1.5 * c[C_PERIOD]:
        nx[sc + BRIDGED] += 1.0
        nx[sc + MAX_BRIDGED] = max(nx[sc + MAX_BRIDGED], h)
    code = _push(nx, c, ic, s, y, u)
    if code != 0:
        return code
    newest = count - 1
    if newest >= 2 * m:
        lo = newest - 2 * m
        frm = newest - m if newest > 2 * m else 0
        if _centre(nx, c, ic, wk, newest, lo, 2 * m + 1, frm, newest - m + 1) != 0:
            return _NON_FINITE_TERM
    if count >= 5:
        _encoder(nx, c, ic, wk)
    _publish(nx, ic, y)
    if count < W + 1:
        DT.write_extras(nx, ic[I_SDET], n, 0.0, nx, ic[I_EXTRA])
        return 0
    code = _estimate(nx, c, ic, wk)
    if code != 0:
        return code
    if nx[sc + VALID] == 0.0:                   # the first estimate of this run
        nx[sc + VALID] = 1.0
        nx[GUARANTEED] = s
    nx[CONVERGED] = 1.0
    g = _scale(nx, ic, wk)
    DT.update(nx, ic[I_SDET], c, ic[I_DET], n, h, nx[ic[I_UI]:ic[I_UI] + n], g, nx,
              ic[I_EXTRA])
    worst = 0.0
    lo = ic[I_EXTRA] + DT.X_HEAD + 2 * n
    for i in range(n):
        if nx[lo + i] > 0.0:
            worst = max(worst, abs(nx[ic[I_UI] + i]) / nx[lo + i])
    nx[HEALTH] = worst
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, a, b, y, u)
    if op == J.FIRST:
        return _first(nx, c, ic, wk, y, u)
    if op == J.RESTART:
        return _restart(st, c, ic)
    return 0


@jit
def refresh(st, c, ic):
    """Every sample in the ring gets its model terms again (the tree's rows changed: a
    payload); what the window holds then agrees with the new model. 0, or 1 when a term is
    not finite (the state is then unusable: the caller restarts)."""
    count = int(st[ic[I_SC] + COUNT])
    W = ic[I_W]
    for j in range(min(count, W + 1)):
        if _terms(st, c, ic, _slot(st, ic, j), True) != 0:
            return 1
    return 0
