"""Acquire, then track: a guaranteed-time observer hands over to a Kalman tracker.

``observer.type: track`` composes two observers configured by their own sections:

- the **acquirer** (``track.acquirer``: single_delay, prescribed_time, hosm,
  newton_inversion or global_norm) runs from every (re)start.  Its estimate is published
  until the hand-over, at its guaranteed time (``single_delay``: tau, ``prescribed_time``:
  T) or, for an acquirer without one, when its own certificate holds: its output residual
  stayed below ``certificate_sigmas`` measurement standard deviations for
  ``certificate_samples`` samples in a row;
- the **tracker** (``track.tracker``): the ``ekf`` section, or the ``luenberger`` section
  in its Kalman design run as the covariance-propagating Kalman filter of the same model
  (A x + B u + F(C x, u), process noise intensities as given, the measurement noise
  intensity divided by ``sample_period`` into a per-sample variance: the filter whose
  steady state is that design).  At the hand-over it starts from the acquirer's estimate
  with the covariance the acquirer's noise leaves in that estimate, measured once per
  configuration by running a fresh acquirer on measurement noise alone
  (``initial_covariance`` overrides it).  From then on its estimate is published.

**Re-acquisition.**  While tracking, the tracker's normalised innovation squared (NIS,
chi-square with p degrees of freedom when the tracker is consistent) is summed over the
last ``window`` samples, each term clipped at threshold / ``min_inconsistent``: one spike
adds at most that (it is not a re-acquisition), a run of ``min_inconsistent`` inconsistent
samples re-acquires whatever the others (fewer, on top of a window of ordinary terms).
The sum of a consistent tracker exceeds ``chi2.isf(false_alarm, p * window)`` with
probability at most ``false_alarm`` per test, one test per sample: at most
``false_alarm / sample_period`` false alarms per second (1e-9 at 1 kHz: one in 11.6 days).
When it does, the acquirer restarts at that sample; the tracker keeps running and its
estimate stays published (the acquirer's estimate before its guaranteed time is not an
estimate of anything), flagged as not converged, until the acquirer hands over again.

Outputs: ``convergence`` carries ``mode`` (0 acquiring, 1 tracking, 2 re-acquiring),
``handovers`` and ``reacquisitions`` since the last (re)start after the common fields
(so a restarted observer publishes what a fresh one does; /diagnostics has the totals);
``converged`` is 1 exactly while tracking; ``health`` is the window statistic over its
threshold (>= 1 re-acquires).  No unknown-input estimate is published (the tracker has
none).

This module is the design (parameters, the children, the test's threshold, the hand-over
covariance, diagnostics); the observer that runs it is the compiled composition
(adapter.py's :class:`TrackObserver` and kernel.py, protocol in observers/kernel.py), for
every acquirer, one whose estimate is mapped back to the plant's coordinates included
(global_norm's chain_map: its kernel publishes plant coordinates).  ROS-free.
"""
from __future__ import annotations

import abc
import math
import re
from typing import Any, Callable

import numpy as np
from scipy.stats import chi2

from ..base import ConfigError, Observer, Param
from ..ekf import ExtendedKalmanFilter

P = "track."
ACQUIRERS = ("single_delay", "prescribed_time", "hosm", "newton_inversion", "global_norm")
#: a tracker is a compiled Kalman filter: st[HEALTH] its NIS, ``R`` its per-sample
#: measurement covariance, ``P0`` its (re)start covariance (settable: the hand-over's)
TRACKERS = ("luenberger", "ekf", "joint_kalman")
ACQUIRING, TRACKING, REACQUIRING = 0, 1, 2
MODE_NAMES = {ACQUIRING: "acquiring", TRACKING: "tracking", REACQUIRING: "re-acquiring"}
#: samples of measurement noise the acquirer's noise covariance is measured on (after its
#: guaranteed time, or after as many samples for an acquirer without one)
NOISE_SAMPLES = 2000
#: at most this many samples are run before NOISE_SAMPLES are measured (bounded start-up)
MAX_NOISE_SKIP = 20_000
NOISE_SEED = 20261201


#: what builds an observer from its type name and typed config (observers/registry.py make)
Make = Callable[[str, dict], Observer]


class TrackDesign(Observer):
    """The composition's design: its children, its test's constants, the hand-over
    covariance, its diagnostics (the running composition, adapter.py, keeps the state)."""

    TYPE = "track"
    DESCRIPTION = ("acquire, then track: a guaranteed-time observer hands over to a Kalman "
                   "tracker, with innovation-gated re-acquisition")
    HEALTH_NAME = "window NIS statistic / its alarm threshold (>= 1: re-acquire); 0 untracked"
    #: the sections of the observers this one composes (the node declares them too)
    CHILD_ROLES = ("acquirer", "tracker")
    CONVERGENCE_EXTRA = ("mode", "handovers", "reacquisitions")
    PARAMS = (
        Param("acquirer", "string", None, "the guaranteed-time observer that acquires, "
              "configured by its own section", choices=ACQUIRERS),
        Param("tracker", "string", None, "the Kalman tracker, configured by its own section "
              "(luenberger: design kalman)", choices=TRACKERS),
        Param("window", "int", 50, "samples in the NIS consistency test", min=2, max=100000,
              read_only=False),
        Param("false_alarm", "double", 1e-9, "probability that one window test of a "
              "consistent tracker fails (one test per sample)", gt=0.0, max=0.1,
              read_only=False),
        Param("min_inconsistent", "int", 5, "each NIS term is clipped at threshold / this: "
              "this many inconsistent samples in a row re-acquire, one spike does not", min=2,
              max=100000, read_only=False),
        Param("certificate_samples", "int", 50, "acquirers without a guaranteed time: hand "
              "over once the output residual stayed below certificate_sigmas measurement "
              "standard deviations for this many samples", min=1, max=1000000,
              read_only=False),
        Param("certificate_sigmas", "double", 5.0, "see certificate_samples", gt=0.0,
              read_only=False),
        Param("sample_period", "double", 0.001, "nominal sample period (s): the acquirer's "
              "noise covariance is measured at it, a luenberger tracker's noise intensity is "
              "divided by it, and the false-alarm rate per second is false_alarm / it",
              gt=0.0, max=10.0, read_only=False),
        Param("initial_covariance", "double_array", [], "n diagonal entries of the tracker's "
              "covariance at the hand-over (empty: measured from the acquirer's noise gain)",
              min=0.0, read_only=False),
    )

    def __init__(self, cfg: dict, make: Make):
        """``cfg``: the typed parameters, and per child role its (type name, typed config)
        under ``<role>_observer``; ``make`` builds the children."""
        (acq_type, acq_cfg), (trk_type, trk_cfg) = cfg["acquirer_observer"], cfg["tracker_observer"]
        self._make_acquirer = lambda: make(acq_type, acq_cfg)
        self.acquirer = self._make_acquirer()
        self.tracker = _kalman_tracker(make, trk_type, trk_cfg, cfg["sample_period"])
        a, k = self.acquirer, self.tracker
        for what in ("n_states", "n_outputs", "n_inputs"):
            if getattr(a, what) != getattr(k, what):
                raise ConfigError(P + "tracker", f"the tracker ({cfg['tracker']}) has "
                                  f"{getattr(k, what)} {what[2:]}, the acquirer "
                                  f"({cfg['acquirer']}) {getattr(a, what)}: both must describe "
                                  "the same plant")
        self.n_states, self.n_outputs, self.n_inputs = a.n_states, a.n_outputs, a.n_inputs
        self.state_names = list(a.state_names)
        self.window = cfg["window"]
        self.threshold = float(chi2.isf(cfg["false_alarm"], self.n_outputs * self.window))
        self.false_alarm = cfg["false_alarm"]
        self.clip = self.threshold / cfg["min_inconsistent"]
        self.certificate_samples = cfg["certificate_samples"]
        self.sigma_y = np.sqrt(np.diag(self.tracker.R))
        self.certificate_residual = cfg["certificate_sigmas"] * float(np.linalg.norm(self.sigma_y))
        self.sample_period = cfg["sample_period"]
        p0 = cfg["initial_covariance"]
        if p0:
            if len(p0) != self.n_states or min(p0) <= 0:
                raise ConfigError(P + "initial_covariance", f"expected {self.n_states} positive "
                                  f"values, got {p0}")
            self.handover_covariance, self.covariance_source = np.diag(p0), "given"
        else:
            self.handover_covariance = self._noise_covariance()
            self.covariance_source = "measured: the acquirer on measurement noise alone"

    # -- the acquirer's noise gain ---------------------------------------------------------
    def _noise_covariance(self) -> np.ndarray:
        """Covariance of a fresh acquirer's estimate on measurement noise alone (the
        tracker's per-sample variances, zero input, zero state), after its guaranteed time;
        the tracker's own initial covariance when the acquirer cannot run on it."""
        acq = self._make_acquirer()
        h = self.sample_period
        gt = acq.guaranteed_time
        skip = math.ceil(gt / h) + 1 if math.isfinite(gt) else NOISE_SAMPLES
        if skip > MAX_NOISE_SKIP:
            raise ConfigError(P + "sample_period", f"measuring the acquirer's noise covariance runs "
                              f"it past its guaranteed time ({gt:.4g} s): {skip:.3g} samples of "
                              f"{h:g} s, more than {MAX_NOISE_SKIP}; give {P}initial_covariance, a "
                              "longer sample period or a shorter guaranteed time")
        rng = np.random.default_rng(NOISE_SEED)
        u = np.zeros(self.n_inputs)
        xs = []
        try:
            acq.reset(0.0)
            for k in range(skip + NOISE_SAMPLES):
                acq.update_checked(k * h, self.sigma_y * rng.standard_normal(self.n_outputs), u)
                if k >= skip:
                    xs.append(np.array(acq.estimate, dtype=float))
            C = np.cov(np.array(xs).T).reshape(self.n_states, self.n_states)
        except Exception:  # noqa: BLE001  any failure: fall back to the tracker's own P0
            return self.tracker.P0.copy()
        if not np.all(np.isfinite(C)):
            return self.tracker.P0.copy()
        C = 0.5 * (C + C.T)
        # keep it positive definite: a floor of 1e-12 of its scale on the diagonal
        return C + np.eye(self.n_states) * max(1e-300, 1e-12 * float(np.trace(C)))

    # -- what the running composition reports (its class keeps the state) --------------------
    @abc.abstractmethod
    def _summary(self) -> tuple[int, int, int, int, int, float, int]:
        """(mode, hand-overs and re-acquisitions over the observer's life, the same since
        the last restart, the NIS window's sum and its length)."""

    @property
    def mode(self) -> str:
        return MODE_NAMES[self._summary()[0]]

    def diagnostics(self) -> dict[str, Any]:
        mode, handovers, reacq, run_handovers, run_reacq, win_sum, win_len = self._summary()
        out = {
            "mode": MODE_NAMES[mode],
            "hand-overs": str(handovers),
            "re-acquisitions": str(reacq),
            "since the last restart": f"{run_handovers} hand-over(s), "
                                      f"{run_reacq} re-acquisition(s)",
            "NIS window sum / threshold": f"{win_sum:.4g} / {self.threshold:.4g} over "
                                         f"{win_len} of {self.window} samples",
            "false alarms (bound)": f"{self.false_alarm:.3g} per test, "
                                    f"{self.false_alarm / self.sample_period * 3600:.3g} per "
                                    f"hour at {1 / self.sample_period:g} Hz",
            "hand-over covariance sqrt(diag)": np.array2string(
                np.sqrt(np.diag(self.handover_covariance)), precision=3),
            "hand-over covariance source": self.covariance_source,
        }
        out.update({f"acquirer: {k}": v for k, v in self.acquirer.diagnostics().items()})
        out.update({f"tracker: {k}": v for k, v in self.tracker.diagnostics().items()})
        return out


def _kalman_tracker(make: Make, type_name: str, cfg: dict,
                    sample_period: float) -> ExtendedKalmanFilter:
    """The tracker: the ekf as configured, or the Kalman filter of a luenberger section."""
    if type_name != "luenberger":                  # a Kalman filter already (TRACKERS)
        return make(type_name, cfg)
    if cfg["design"] != "kalman":
        raise ConfigError(P + "tracker", "a luenberger tracker needs luenberger.design: kalman "
                          "(its process and measurement noise are the tracker's noise model)")
    lu = make(type_name, cfg)                         # validates A, B, C, F and the noise
    n, p, m = lu.n_states, lu.n_outputs, lu.n_inputs
    states = [f"s{i}" for i in range(n)]
    inputs = [f"u{i}" for i in range(m)]

    def row(M, i, names):
        return " + ".join(f"({float(M[i, j])!r})*{names[j]}" for j in range(M.shape[1])
                          if M[i, j] != 0.0) or "0"
    outputs = [f"({row(lu.C, j, states)})" for j in range(p)]
    F = cfg["F"] or ["0"] * n
    f = [f"{row(lu.A, i, states)} + {row(lu.B, i, inputs) if m else '0'} + ("
         + re.sub(r"\by(\d+)\b", lambda mo: outputs[int(mo.group(1))], F[i]) + ")"
         for i in range(n)]
    ekf_cfg = dict(states=states, inputs=inputs, constants=[], f=f,
                   h=[row(lu.C, j, states) for j in range(p)],
                   process_noise=list(cfg["process_noise"]),
                   measurement_noise=[r / sample_period for r in cfg["measurement_noise"]],
                   initial_covariance=[], initial_state=cfg["initial_state"],
                   input_hold=cfg["input_hold"], max_step=0.01)
    k = make("ekf", ekf_cfg)
    k.state_names = list(lu.state_names)
    return k
