"""Synthetic joint streams for the velocity tests (no model of any observer in them): per
joint a closed-form smooth trajectory with velocity reversals (a sum of sines), sampled at
jittered instants (t_k = k h + U(-jitter, jitter), the stamps ARE the instants), the encoder's
Gaussian noise and quantisation, lost messages; as arrays, as a per-joint JointState bag
(``/arm/joint_states``, the truth on ``/arm/true_joint_states``), and run through a runner.

Seeds: the trajectory, the noise, the jitter and the losses each draw from their own
stream (``numpy.random.default_rng([seed, tag])``), so a second seed is another bag of the
same kind and turning the jitter on changes nothing else.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

JOINTS = [f"joint_a{i}" for i in range(1, 8)]
TRAJECTORY, NOISE, JITTER, LOSS, STAMP = 1, 2, 3, 4, 5
SIGMA, RESOLUTION = 1e-5, 2.0 ** -18


@dataclass
class Stream:
    t: np.ndarray          # (K,) s, the actual sampling instants (= stamps)
    y: np.ndarray          # (K, J) encoder positions
    q: np.ndarray          # (K, J) true positions
    v: np.ndarray          # (K, J) true velocities


#: the frequencies (rad/s) of a joint's motion at speed 1: every seed moves a joint with the
#: same character (a task repeated), each its own realisation
BASE_FREQUENCIES = np.array([0.7, 1.3, 2.3, 3.7])


def trajectory(t: np.ndarray, seed: int, joints: int, speed=None):
    """(q, v), each (K, J): per joint four sines at BASE_FREQUENCIES times the joint's speed
    factor (default 0.5 ... 2 over the joints), each +-10 % by the seed, amplitudes
    0.2 rad +-20 % and phases by the seed."""
    rng = np.random.default_rng([seed, TRAJECTORY])
    speed = np.geomspace(0.5, 2.0, joints) if speed is None else np.asarray(speed, float)
    q = np.zeros((t.size, joints))
    v = np.zeros((t.size, joints))
    m = BASE_FREQUENCIES.size
    for j in range(joints):
        a = 0.2 * rng.uniform(0.8, 1.2, m)
        w = BASE_FREQUENCIES * rng.uniform(0.9, 1.1, m) * speed[j]
        ph = rng.uniform(0, 2 * math.pi, m)
        for am, wm, pm in zip(a, w, ph):
            q[:, j] += am * np.sin(wm * t + pm)
            v[:, j] += am * wm * np.cos(wm * t + pm)
    return q, v


def stream(seed: int, duration: float = 5.0, period: float = 1e-3, jitter: float = 50e-6,
           loss: float = 0.0, joints: int = 7, sigma: float = SIGMA,
           resolution: float = RESOLUTION, speed=None, start: float = 1.0,
           stamp_noise: float = 0.0) -> Stream:
    """A stream of ``duration`` s at 1/period (see the module doc); stamps on the whole
    microsecond (the observers' clock), from ``start`` s.  ``stamp_noise``: the stamps are
    NOT the instants but off them by U(-stamp_noise, stamp_noise) (a driver stamping on
    receipt); the truth stays at the instants, listed at the stamps."""
    k = np.arange(int(round(duration / period)))
    t = start + k * period
    if jitter > 0:
        t = t + np.random.default_rng([seed, JITTER]).uniform(-jitter, jitter, k.size)
    t = np.round(t * 1e6) / 1e6
    if loss > 0:
        keep = np.random.default_rng([seed, LOSS]).random(k.size) >= loss
        keep[0] = True
        t = t[keep]
    q, v = trajectory(t - start, seed, joints, speed)
    y = q + sigma * np.random.default_rng([seed, NOISE]).standard_normal(q.shape)
    if resolution > 0:
        y = np.round(y / resolution) * resolution
    if stamp_noise > 0:
        off = np.random.default_rng([seed, STAMP]).uniform(-stamp_noise, stamp_noise, t.size)
        stamps = np.round((t + off) * 1e6) / 1e6
        order = np.argsort(stamps, kind="stable")
        t, y, q, v = stamps[order], y[order], q[order], v[order]
    return Stream(t, y, q, v)


def write_bag(path: Path, s: Stream, names=None) -> Path:
    """The stream as a per-joint bag: JointState positions (stamp = log time = the instant),
    the truth's positions and velocities."""
    from fto_ros.bag import BagWriter
    names = list(names or JOINTS[:s.y.shape[1]])
    zeros = np.zeros(len(names))
    with BagWriter(path) as bag:
        for k in range(s.t.size):
            t_ns = int(round(s.t[k] * 1e9))
            bag.joint_state("/arm/joint_states", t_ns, t_ns, names, s.y[k], (), zeros)
            bag.joint_state("/arm/true_joint_states", t_ns, t_ns, names, s.q[k], s.v[k], zeros)
    return path


def estimates(runner, s: Stream) -> tuple[np.ndarray, np.ndarray]:
    """(estimates (K, J, n), accepted (K, J)) of ``runner`` (per-joint or one joint) on the
    stream's measurements, one compiled block; an observer with an input gets u = 0 with
    every sample (the motion is then its unknown input, the same for every stream)."""
    from fto_ros.runner import loop as L
    K, J = s.y.shape
    m = runner.observer.n_inputs
    if not m:
        blk = runner.process_block(np.full(K, L.MEASUREMENT, np.int8), s.t, s.y[:, :, None])
        return blk.estimate, blk.status == L.OUTPUT
    kind = np.tile(np.array([L.INPUT, L.PAIRED], np.int8), K)
    vals = np.zeros((2 * K, J, max(m, 1)))
    vals[1::2, :, 0] = s.y
    blk = runner.process_block(kind, np.repeat(s.t, 2), vals)
    return blk.estimate[1::2], blk.status[1::2] == L.OUTPUT


def velocity_rms(runner, s: Stream, after: float = 0.5, velocity: int = 1) -> np.ndarray:
    """Per joint, the RMS of the velocity estimate's error from ``after`` s on."""
    x, ok = estimates(runner, s)
    late = (s.t - s.t[0]) >= after
    out = np.zeros(s.y.shape[1])
    for j in range(out.size):
        m = ok[:, j] & late
        out[j] = math.sqrt(float(np.mean((x[m, j, velocity] - s.v[m, j]) ** 2)))
    return out


def backward_difference_rms(s: Stream, after: float = 0.5) -> np.ndarray:
    """Per joint, the RMS error of (y_k - y_k-1) / (t_k - t_k-1), from ``after`` s on."""
    v = np.diff(s.y, axis=0) / np.diff(s.t)[:, None]
    late = (s.t[1:] - s.t[0]) >= after
    return np.sqrt(np.mean((v[late] - s.v[1:][late]) ** 2, axis=0))
