"""Plausibility limits and the outlier gate: what the runner refuses before a sample can
reach the observer.  No observer knowledge.

**Limits.**  A measurement or input whose absolute value exceeds its per-channel limit
(``limits.measurement``, ``limits.input``: one value for every channel, or one per
channel) is rejected as ``measurement_implausible`` / ``input_implausible``: a finite
1e300 from a glitching driver never reaches an integrator.

**Outlier gate.**  Each measurement is compared with the linear extrapolation of the last
two accepted ones (variable step): the innovation ``e = y - y_pred`` of a model-free
predictor, available for every observer before its update, so a rejected sample never
touches the observer's state; it is expressed in units of the innovation of equal steps of
the typical length (``_innovation``), so dropped samples do not look like glitches.  Its
recent scale ``sigma`` is the RMS of e over the last ``outlier.window`` accepted samples
(an exponentially weighted mean square), floored at ``outlier.min_scale``.  Once the
observer has converged (the runner says when) and the scale has a quarter window of
history, a sample with ``|e_i| > threshold * sigma_i`` on any channel is rejected as
``outlier``.  On the committed bags the largest ratio |e| / sigma is 4.5 (noisy DC motor,
cubic escape); the default threshold is 20.

A real change (a collision, a step of the signal) also starts as "outliers"; what tells it
from a glitch is that it persists: the rejected samples are extrapolated among
themselves, and ``outlier.confirm`` consecutive ones that agree with each other (their
own innovations within the threshold) are accepted as the new signal: the gate re-bases
on them (counted under ``outlier_rebase``).  Random junk never agrees with itself; after
``outlier.max_consecutive`` rejections in a row the gate re-bases anyway, so it can never
lock the observer out of a signal whose character changed (e.g. much noisier).  Each
re-base also restarts the scale estimate.

The gate's memory is a slice ``g`` of the runner's state (``layout`` gives its places for p
channels and ``confirm`` held samples); its functions are compiled (core/jit.py).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..core.errors import ConfigError
from ..core.jit import jit

#: no gating when one of the last two steps is this many times longer than the other (a
#: line through samples either side of a pause says nothing about the next one)
MAX_STEP_RATIO = 4.0
ACCEPT, OUTLIER, REBASE = 0, 1, 2
# scalar places in the gate's slice; arrays follow (see ``size``)
NPREV, PT0, PT1, N, NHELD, RUN, H = range(7)
_SCALARS = 7


@jit
def size(p, confirm):
    """Floats of the gate's memory for p channels and ``confirm`` held samples."""
    return _SCALARS + 4 * p + confirm * (1 + p)


def channel_limits(values: Sequence[float], n: int, parameter: str) -> np.ndarray:
    """Per-channel limits from one value (all channels) or n values; ConfigError otherwise."""
    if len(values) == 1:
        return np.full(n, float(values[0]))
    if len(values) != n:
        raise ConfigError(parameter, f"expected 1 value (every channel) or {n}, got {len(values)}")
    return np.asarray(values, dtype=float)


@jit
def exceeds(v, limits):
    """Whether any |v_i| > limits_i."""
    for i in range(v.shape[0]):
        if abs(v[i]) > limits[i]:
            return True
    return False


@jit
def clear(g, p, confirm):
    """Forget the history (a restart of the observer, a re-base)."""
    g[:size(p, confirm)] = 0.0


@jit
def _innovation(g, p, t1, y1, t2, y2, t, y, streak, e):
    """e = y minus the line through (t1, y1) and (t2, y2), in units of the innovation of
    equal steps of the typical length; False when there is no usable line.

    Irregular steps (samples dropped on a loaded machine) make the raw innovation larger
    for a reason that is not a glitch: with r = (t - t2)/(t2 - t1) its noise part grows
    by sqrt((1 + r^2 + (1 + r)^2) / 6) and the extrapolation error of a smooth signal by
    (t - t2)(t - t1) / (2 h^2) (h: the typical step); the larger divides it.  In a streak
    of rejected samples only the noise part does (the line of the last accepted samples
    is what they are measured against: junk must not get through by lasting).  After a
    pause in the accepted history (one step much longer than the other) there is no line.
    """
    h1 = t2 - t1
    d = t - t2
    if not h1 > 0 or not d > 0 or h1 > MAX_STEP_RATIO * d \
            or (d > MAX_STEP_RATIO * h1 and not streak):
        return False
    r = d / h1
    f = math.sqrt((1.0 + r * r + (1.0 + r) ** 2) / 6.0)
    hh = g[H]
    if not streak and hh > 0:
        f = max(f, d * (d + h1) / (2.0 * hh * hh))
    for i in range(p):
        e[i] = (y[i] - (y2[i] + (y2[i] - y1[i]) * r)) / f
    return True


@jit
def _within(g, p, e):
    lim = g[_SCALARS + 3 * p:_SCALARS + 4 * p]
    for i in range(p):
        if not abs(e[i]) <= lim[i]:
            return False
    return True


@jit
def check(g, p, confirm, threshold, min_history, max_consecutive, floor, t, y, active, e):
    """ACCEPT, OUTLIER (reject y at t) or REBASE (accept it as a confirmed change; the
    caller counts it).  Call ``accepted`` for every sample the observer then takes.  ``e``
    is scratch of p floats."""
    if not threshold > 0 or not active or g[N] < min_history:
        return ACCEPT
    py0 = g[_SCALARS:_SCALARS + p]
    py1 = g[_SCALARS + p:_SCALARS + 2 * p]
    if not _innovation(g, p, g[PT0], py0, g[PT1], py1, t, y, g[RUN] > 0, e):
        return ACCEPT
    ms = g[_SCALARS + 2 * p:_SCALARS + 3 * p]
    lim = g[_SCALARS + 3 * p:_SCALARS + 4 * p]
    for i in range(p):
        lim[i] = threshold * max(math.sqrt(ms[i]), floor[i])
    if _within(g, p, e):
        if g[RUN] > 0:
            g[NHELD] = 0.0
            g[RUN] = 0.0
        return ACCEPT
    # the held rejected samples, oldest first: the last `confirm` of them
    ht = g[_SCALARS + 4 * p:_SCALARS + 4 * p + confirm]
    hy = g[_SCALARS + 4 * p + confirm:_SCALARS + 4 * p + confirm * (1 + p)].reshape(confirm, p)
    nh = int(g[NHELD])
    if nh == confirm:
        for k in range(confirm - 1):
            ht[k] = ht[k + 1]
            hy[k, :] = hy[k + 1, :]
        nh -= 1
    ht[nh] = t
    hy[nh, :] = y
    nh += 1
    g[NHELD] = nh
    g[RUN] += 1.0
    # the last `confirm` rejected samples continue each other: a persisting change
    persisting = nh == confirm
    if persisting:
        for k in range(2, nh):
            if not (_innovation(g, p, ht[k - 2], hy[k - 2], ht[k - 1], hy[k - 1], ht[k], hy[k],
                                False, e) and _within(g, p, e)):
                persisting = False
                break
    if persisting or g[RUN] >= max_consecutive:
        tb = ht[nh - 2] if nh >= 2 else 0.0
        yb = hy[max(nh - 2, 0), :].copy()
        clear(g, p, confirm)
        if nh >= 2:
            g[NPREV] = 1.0
            g[PT1] = tb
            g[_SCALARS + p:_SCALARS + 2 * p] = yb
        return REBASE
    return OUTLIER


@jit
def accepted(g, p, alpha, t, y, e):
    """Record a sample the observer took."""
    npv = int(g[NPREV])
    py0 = g[_SCALARS:_SCALARS + p]
    py1 = g[_SCALARS + p:_SCALARS + 2 * p]
    if npv > 0:
        step = t - g[PT1]
        if step > 0:
            g[H] = step if g[H] == 0 else g[H] + alpha * (step - g[H])
    if npv == 2:
        if _innovation(g, p, g[PT0], py0, g[PT1], py1, t, y, False, e):
            a = alpha if g[N] > 0 else 1.0
            ms = g[_SCALARS + 2 * p:_SCALARS + 3 * p]
            for i in range(p):
                ms[i] = ms[i] + a * (e[i] * e[i] - ms[i])
            g[N] += 1.0
    if npv >= 1:
        g[PT0] = g[PT1]
        py0[:] = py1
    g[PT1] = t
    py1[:] = y
    g[NPREV] = min(npv + 1, 2)


def summary(g: np.ndarray, p: int, threshold: float, min_history: int) -> str:
    """One line for /diagnostics."""
    if not threshold > 0:
        return "off"
    n = int(g[N])
    if n < min_history:
        return f"learning ({n} of {min_history} samples)"
    ms = g[_SCALARS + 2 * p:_SCALARS + 3 * p]
    return "sigma " + ", ".join(f"{math.sqrt(v):.3g}" for v in ms)
