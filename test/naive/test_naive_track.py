"""Naive reference of ``track`` (docs/track.md): acquire with ``single_delay``, hand over to
the Kalman filter of the ``luenberger`` section, test the filter's NIS over a window,
re-acquire; against the package through the runner at every sample, on the DC motor with
a collision (+4 rad/s on q_dot, as bags/dc_motor_collision) that makes it re-acquire.

The rules, from docs/track.md:
- acquiring: the acquirer takes the sample and its estimate is published; at the first
  sample where the acquirer's time since its start reaches its guaranteed time (tau) the
  tracker starts from the acquirer's estimate with the hand-over covariance
  (``track.initial_covariance``, given here: the measured one is a Monte Carlo run of the
  package's) and corrects with that same sample (no prediction); its estimate is published
  from then on;
- tracking: the tracker takes the sample; its NIS, clipped at threshold / min_inconsistent,
  joins a window of the last ``window`` terms; the test fails when the window is full and
  its sum exceeds threshold = chi2.isf(false_alarm, p window): the acquirer restarts and
  takes this sample as its first, the window empties;
- re-acquiring: the tracker keeps taking the samples (its estimate published, no window)
  and the acquirer too, until the acquirer's guaranteed time: a new hand-over.
The tracker is the continuous-discrete Kalman filter of x' = A x + B u + F(C x, u) with the
luenberger section's process noise and the measurement intensity over ``sample_period`` as
the per-sample variance (naive_ekf.py), the acquirer naive_single_delay.py's.

Tolerance 1e-10 of each state's scale: the larger of the two children's (test_naive_ekf.py,
and single_delay's 1e3 eps cond(S) = 7.5e-12 at k = 200, tau = 0.05); the modes must agree
at every sample, and the window sums that decide them must be away from the threshold by
far more than that (checked: a decision within 1e-6 of the threshold would make the test
ill-posed, not the package wrong).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np
from scipy.stats import chi2

import naive_ekf as NE
import naive_plants as NP
import naive_single_delay as SD
import naive_support as NS

FAMILY = "track"
FORMS = ("single_delay+luenberger",)
TOL = 1e-10
ACQUIRING, TRACKING, REACQUIRING = 0, 1, 2
P_HANDOVER = [1e-6, 1e-2, 4e-4]


def track_reference(t, y, u, flat, design):
    """(estimate, mode, the window sums at each test) at every stamp."""
    h = NS.steps(t)[0]
    window, p = flat["track.window"], 1
    threshold = chi2.isf(flat["track.false_alarm"], p * window)
    clip = threshold / flat["track.min_inconsistent"]
    Qc = np.diag(flat["luenberger.process_noise"])
    R = np.diag(flat["luenberger.measurement_noise"]) / flat["track.sample_period"]
    kf = NE.Filter(Qc, R, 0.01, NE.dc_f, NE.dc_jacobian, np.array([[1.0, 0.0, 0.0]]))
    acq = SD.Continuous(design, h)
    acq.first(y[0], u[0])
    mode, terms, est, modes, sums = ACQUIRING, deque(maxlen=window), [], [], []

    def acquired():
        return (acq.samples - 1) * h >= design.tau - 1e-9

    def hand_over(j):
        kf.start(acq.estimate, np.diag(P_HANDOVER))
        kf.take(0.0, y[j], u[j])
        terms.clear()
        return TRACKING
    if acquired():
        mode = hand_over(0)
    est.append(acq.estimate if mode == ACQUIRING else kf.x)
    modes.append(mode)
    for j in range(1, len(t)):
        if mode == ACQUIRING:
            acq.take(y[j], u[j - 1])
            if acquired():
                mode = hand_over(j)
        else:
            kf.take(h, y[j], u[j - 1])
            if mode == REACQUIRING:
                acq.take(y[j], u[j - 1])
                if acquired():
                    mode = hand_over(j)
            else:
                terms.append(min(kf.nis, clip) if math.isfinite(kf.nis) else clip)
                total = math.fsum(terms)
                if len(terms) == window:
                    sums.append(total / threshold)
                    if total > threshold:
                        mode = REACQUIRING
                        terms.clear()
                        acq.first(y[j], u[j])
        est.append(acq.estimate if mode == ACQUIRING else kf.x)
        modes.append(mode)
    return np.array(est), np.array(modes), np.array(sums)


def test_track_matches_its_naive_reference():
    jump = 150
    t = NS.times(0.5, 300, 1000)
    t, x, y, u = NP.dc_motor_stream(t, jump=(jump, [0.0, 4.0, 0.0]))
    flat = NS.flat_params("dc_motor_plant", "dc_motor_acquire_track", single_delay__k=200.0,
                          single_delay__tau=0.05, track__initial_covariance=P_HANDOVER,
                          track__min_inconsistent=5, outlier__threshold=0.0)
    # (the runner's outlier gate off: it would refuse the collision's samples before the
    # observer sees them; the gate is the runner's, not this family's)
    assert (flat["track.acquirer"], flat["track.tracker"]) == ("single_delay", "luenberger")
    design = SD.Design(200.0, 0.05)
    ref, modes, sums = track_reference(t, y, u, flat, design)
    est, _, conv = NS.run(flat, t, y, u)
    got_modes = conv[:, 5].astype(int)                  # the first extra value: mode
    assert np.array_equal(got_modes, modes), \
        f"modes differ first at sample {int(np.argmax(got_modes != modes))}"
    # the run went through every rule: hand-over, re-acquisition after the jump, hand-over
    changes = [(int(j), int(modes[j])) for j in np.flatnonzero(np.diff(modes)) + 1]
    print("mode changes (sample, mode):", changes)
    assert [m for _, m in changes] == [TRACKING, REACQUIRING, TRACKING]
    assert changes[1][0] > jump
    assert np.all(np.abs(sums - 1.0) > 1e-6), "a window test too close to its threshold"
    NS.assert_close("track (single_delay -> luenberger)", est, ref, TOL)

