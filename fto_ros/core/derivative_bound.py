"""A bound on the k-th time derivative of a sampled signal, from a recording (ROS-free).

For ``fto-design --suggest-from BAG``: hosm's M bounds a derivative of its differentiators'
input, and a recording shows how large that derivative gets.  Derivatives of a sampled,
noisy signal are estimated by local polynomial least squares (Savitzky-Golay on the actual
sample times, so irregular sampling is fine): around each sample a polynomial of degree
k + 2 is fitted to a window of w samples and its k-th derivative taken at the centre.  A
short window follows the signal's peaks, a long one averages the noise: the noise part of
an estimate is sigma |g| (sigma from the fits' residuals, g the window's derivative
weights, both computed), and the shortest window whose largest noise excursion
(:data:`EXCURSION` sigma |g|, over thousands of estimates) is at most :data:`NOISE_FRACTION`
of the largest estimate is used: its largest estimate is the bound.  When no window gets
there the recording's derivative is below its noise: the longest window's largest
estimate plus its noise excursion is returned (an upper bound at that time scale), with
``noise_limited`` set.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import BadArgument

#: the noise excursion accepted, relative to the bound
NOISE_FRACTION = 0.1
#: the largest noise excursion among the estimates, in standard deviations
EXCURSION = 4.0
#: at most this many windows are fitted per window length (evenly spread centres, at most
#: a quarter window apart: the estimates of overlapping windows are alike)
MAX_CENTRES = 4000


@dataclass
class DerivativeBound:
    bound: float             # max |x^(k)| over the recording (the chosen window's estimates)
    window_s: float          # duration of the chosen window
    window_samples: int
    noise: float             # the noise excursion at that window (EXCURSION sigma |g|)
    noise_limited: bool      # no window brought the noise part below NOISE_FRACTION


def _fits(t: np.ndarray, x: np.ndarray, order: int, w: int) -> tuple[np.ndarray, float, float]:
    """(k-th derivative at the centres, median residual RMS, median |g|) for windows of w."""
    half = w // 2
    deg = order + 2
    step = max(1, w // 4, (len(t) - w) // MAX_CENTRES)
    centres = np.arange(half, len(t) - half, step)
    idx = centres[:, None] + np.arange(-half, half + 1)[None, :]
    scale = 0.5 * (t[idx[:, -1]] - t[idx[:, 0]])[:, None]
    s = (t[idx] - t[centres][:, None]) / scale                 # in [-1, 1]: well conditioned
    V = s[..., None] ** np.arange(deg + 1)
    P = np.linalg.pinv(V)                                      # (centres, deg + 1, w)
    coef = np.einsum("cdw,cw->cd", P, x[idx])
    fact = math.factorial(order) / scale[:, 0] ** order
    deriv = coef[:, order] * fact
    gain = np.linalg.norm(P[:, order, :], axis=1) * fact
    resid = x[idx] - np.einsum("cwd,cd->cw", V, coef)
    sigma = np.sqrt(np.sum(resid ** 2, axis=1) / (w - deg - 1))
    return deriv, float(np.median(sigma)), float(np.median(gain))


def derivative_bound(t, x, order: int) -> DerivativeBound:
    """The bound on |x^(order)| over samples x at times t (increasing), see the module doc.
    ValueError when there are too few samples for the shortest window."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    w = order + 5                                   # degree order + 2, two spare samples
    w += 1 - w % 2                                  # odd: a centred window
    if len(t) < 2 * w:
        raise BadArgument(f"{len(t)} samples: at least {2 * w} are needed")
    longest = min(len(t) // 4, 2001)
    while True:
        deriv, sigma, gain = _fits(t, x, order, w)
        peak, noise = float(np.max(np.abs(deriv))), EXCURSION * sigma * gain
        span = float(np.median(t[w - 1:] - t[:len(t) - w + 1]))
        if noise <= NOISE_FRACTION * peak:
            return DerivativeBound(peak, span, w, noise, False)
        nxt = int(w * 1.5) | 1
        if nxt > longest:
            return DerivativeBound(peak + noise, span, w, noise, True)
        w = nxt
