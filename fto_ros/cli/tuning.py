"""What ``fto-tune`` tunes and how it scores a candidate on a bag (ROS-free).

**Knobs** (:func:`knob`): one number per joint (per observer without ``joints``), mapped
onto the observer's parameters:

- ``joint_kalman``: its ``bandwidth`` (Hz), searched from 0.5 Hz to 0.3 / sample_period;
- ``hosm``: a gain scale s (the Luenberger poles times s, M times s^N, N the derivative
  order M bounds: the observer run s times faster), from 0.05 to 20;
- ``single_delay``: a speed s (tau / s), from 0.05 to 20;
- ``ekf``, ``luenberger`` (Kalman design): a noise scale s (the process noise times s^2;
  luenberger's poles design: the poles times s), from 0.01 to 100;
- ``track``: its tracker's knob.

**Scores** (:func:`score`), from the data alone, never from a truth: per joint, the RMS of

- ``prediction``: the one-step-ahead position prediction error, y_k minus the estimate at
  the previous accepted sample carried over the actual step (q + q' dt (+ q'' dt^2 / 2 ...
  for a chain)), which never saw y_k: the Kalman filter's innovation;
- ``heldout``: the same run on the even samples only, scored on each odd sample from the
  even one before it (a held-out encoder subsample);

over the accepted samples from ``after`` s on, pairs across a restart left out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from ..core.errors import ConfigError
from ..replay.blocks import PYTHON
from ..runner import loop as L
from ..runner import joints as JX
from ..runner.runner import Runner

SCORES = ("prediction", "heldout")


@dataclass
class Knob:
    """One number per joint and how it becomes the observer's parameters."""
    parameter: str                     # what the value is, for people ("joint_kalman.bandwidth")
    unit: str
    lo: float
    hi: float
    #: joint values -> {full parameter name: the per-joint values}
    apply: Callable[[np.ndarray], dict[str, list[Any]]]
    #: the (single) tuned parameter's text value per joint, for the file's comment
    shown: Callable[[float, int], str]


def _section(flats: list[Mapping[str, Any]], name: str) -> list[Any]:
    return [f.get(name) for f in flats]


def knob(runner: Runner, flats: list[Mapping[str, Any]]) -> Knob:
    """The knob of ``runner``'s observer (``flats``: each joint's flat parameters);
    ConfigError when it has none."""
    obs = runner.observer
    kind = runner.observer_type
    if kind == "track":
        kind = obs.tracker.TYPE
        obs = obs.tracker
    if kind == "joint_kalman":
        h0 = obs.sample_period
        return Knob("joint_kalman.bandwidth", "Hz", 0.5, 0.3 / h0,
                    lambda v: {"joint_kalman.bandwidth": [[float(x)] for x in v]},
                    lambda v, j: f"{v:.4g}")
    if kind == "hosm":
        poles = _section(flats, "hosm.poles")
        M = _section(flats, "hosm.M")
        if any(not p for p in poles):
            raise ConfigError("hosm.poles", "fto-tune scales hosm's poles: give hosm.poles "
                              "(not an explicit L)")
        N = np.asarray(obs.bounded_orders, dtype=float)
        return Knob("hosm gain scale (poles x s, M x s^N)", "", 0.05, 20.0,
                    lambda v: {"hosm.poles": [[float(x) * s for x in p] for p, s in zip(poles, v)],
                               "hosm.M": [[float(x) * s ** n for x, n in zip(m, N)]
                                          for m, s in zip(M, v)]},
                    lambda v, j: f"{v:.4g}")
    if kind == "single_delay":
        tau = _section(flats, "single_delay.tau")
        return Knob("single_delay speed (tau / s)", "", 0.05, 20.0,
                    lambda v: {"single_delay.tau": [float(t) / s for t, s in zip(tau, v)]},
                    lambda v, j: f"{v:.4g} (tau {float(tau[j]) / v:.4g} s)")
    if kind in ("ekf", "luenberger"):
        if kind == "luenberger" and flats[0].get("luenberger.design", "poles") == "poles":
            poles = _section(flats, "luenberger.poles")
            return Knob("luenberger pole scale (poles x s)", "", 0.05, 20.0,
                        lambda v: {"luenberger.poles": [[float(x) * s for x in p]
                                                        for p, s in zip(poles, v)]},
                        lambda v, j: f"{v:.4g}")
        name = f"{kind}.process_noise"
        q = _section(flats, name)
        return Knob(f"{kind} process noise scale (process_noise x s^2)", "", 0.01, 100.0,
                    lambda v: {name: [[float(x) * s * s for x in qq] for qq, s in zip(q, v)]},
                    lambda v, j: f"{v:.4g}")
    raise ConfigError("observer.type", f"fto-tune tunes joint_kalman, hosm, single_delay, ekf, "
                      f"luenberger and track with one of them as tracker; got {kind}")


def with_values(flat: Mapping[str, Any], joints: list[str], values: Mapping[str, list[Any]]
                ) -> dict[str, Any]:
    """``flat`` with the per-joint ``values``: joint_overrides entries in per-joint mode
    (replacing any for the same parameters, keeping the others), the parameters themselves
    with one observer."""
    out = dict(flat)
    if not joints:
        out.update({k: v[0] for k, v in values.items()})
        return out
    kept = [t for t in (flat.get(JX.OVERRIDES) or [])
            if not (isinstance(t, str) and t.partition("=")[0].strip() in values)]
    out[JX.OVERRIDES] = kept + [override_text(k, v) for k, v in values.items()]
    return out


def override_text(name: str, per_joint: list[Any]) -> str:
    def fmt(v):
        if isinstance(v, list):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        return f"{float(v):.7g}"
    return f"{name}={fmt(per_joint)}"


def chain_terms(runner: Runner) -> list[list[tuple[int, int]]]:
    """Per joint, the (state index, power) pairs of the extrapolation q + q' dt + ...: the
    whole chain of a joint_kalman (alone or tracking), else the position and velocity."""
    obs = runner.observer
    kal = obs if runner.observer_type == "joint_kalman" else getattr(obs, "tracker", None)
    out = []
    for roles in (runner.roles if runner.joints else [None]):
        if kal is not None and getattr(kal, "TYPE", "") == "joint_kalman":
            out.append([(i, i) for i in range(kal.order)])
            continue
        pos = roles.position if roles is not None else 0
        vel = roles.velocity if roles is not None else (1 if obs.n_states > 1 else -1)
        out.append([(pos, 0)] + ([(vel, 1)] if vel >= 0 else []))
    return out


def heldout_mask(rows) -> np.ndarray:
    """The rows of every event but the odd measurement samples (and the input each of
    those carries): what the held-out score feeds."""
    keep = np.ones(rows.kind.size, bool)
    samples = np.flatnonzero(rows.srow >= 0)
    for e in samples[1::2].tolist():
        keep[rows.first[e]:rows.first[e + 1]] = False
    return keep


def score(runner: Runner, rows, keep: np.ndarray | None, after: float) -> np.ndarray:
    """Per joint, the RMS prediction error of ``runner`` run on ``rows`` (the module doc):
    with ``keep`` (a mask of measurement rows fed; None: all), the error on the rows left
    out, each from the last fed sample before it; nan where a joint has no pair."""
    run = np.ones(rows.kind.size, bool) if keep is None else keep
    kind, t, vals, pre = rows.kind[run], rows.t[run], rows.values[run], rows.pre[run]
    good = kind != PYTHON                   # rows the runner takes (an intake reason
    # without a code is counted in Python by the replay: nothing for the score)
    blk = runner.process_block(kind[good], t[good], vals[good], pre[good])
    fed_t, fed_status, fed_x = t[good], blk.status, blk.estimate
    since = blk.convergence[:, :, 0]
    meas_all = (rows.kind == L.MEASUREMENT) | (rows.kind == L.PAIRED)
    J = runner.n_joints
    terms = chain_terms(runner)
    out = np.full(J, np.nan)
    t0 = float(fed_t[0]) if fed_t.size else 0.0
    for j in range(J):
        ok = fed_status[:, j] == L.OUTPUT
        ft, fx, fs = fed_t[ok], fed_x[ok, j], since[ok, j]
        if keep is None:
            yt, yv = ft[1:], vals[good][ok, j, 0][1:]
            src = np.arange(ft.size - 1)
            fresh = fs[1:] == 0.0                  # the first sample after a restart
        else:
            targets = meas_all & ~run & (rows.pre[:, j] == 0)
            yt, yv = rows.t[targets], rows.values[targets, j, 0]
            src = np.searchsorted(ft, yt, side="right") - 1
            fresh = src < 0
            src = np.maximum(src, 0)
        if ft.size < 2:
            continue
        dt = yt - ft[src]
        pred = np.zeros(yt.size)
        for idx, power in terms[j]:
            pred += fx[src, idx] * dt ** power / math.factorial(power)
        use = ~fresh & (yt - t0 >= after) & (dt > 0)
        if use.any():
            out[j] = float(np.sqrt(np.mean((yv[use] - pred[use]) ** 2)))
    return out
