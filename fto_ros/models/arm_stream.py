"""What a real arm's driver does to the samples it publishes (ROS-free): jittered sampling
instants, stamp errors, lost messages and the meaning of JointState.effort.

Each draws from its own random stream (``numpy.random.default_rng([seed, tag])``), so that
turning one on changes nothing else of a run (the trajectory, the encoder noise).
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError, short

#: what JointState.effort carries (fto-simulate --urdf --effort)
EFFORTS = ("commanded", "commanded_no_gravity", "measured", "current")
JITTER, STAMP, LOSS, TORQUE_NOISE, CURRENT_NOISE = 101, 102, 103, 104, 105


def sample_instants(samples: int, period: float, jitter: float, seed: int) -> np.ndarray:
    """t_k = k period + u_k, u_k uniform in [-jitter, jitter] for k >= 1 (t_0 = 0: the run's
    start); jitter below half the period keeps the instants increasing."""
    if not (0.0 <= jitter < 0.5 * period):
        raise ConfigError("jitter", f"must be in [0, {0.5 * period:g}) s (half the period), "
                                    f"got {short(jitter)}")
    t = np.arange(samples) * period
    if jitter > 0 and samples > 1:
        rng = np.random.default_rng([int(seed), JITTER])
        t[1:] += rng.uniform(-jitter, jitter, samples - 1)
    return t


def header_stamps(t: np.ndarray, noise: float, seed: int) -> np.ndarray:
    """The header stamps (int ns) of samples taken at the instants t (s): round(t 1e9) plus an
    error uniform in [-noise, noise] s (0: the actual instants), never below 0."""
    ns = np.round(np.asarray(t, dtype=float) * 1e9)
    if noise > 0:
        rng = np.random.default_rng([int(seed), STAMP])
        ns = ns + np.round(rng.uniform(-noise, noise, ns.size) * 1e9)
    return np.maximum(ns, 0).astype(np.int64)


def lost_messages(samples: int, probability: float, burst: int, seed: int) -> np.ndarray:
    """True where a message is lost: each message not inside a run starts a run of lost ones
    with probability q, its length L uniform in 1..burst, and the message after a run is
    received (no run is longer than burst); q = P / (E[L] (1 - P)) makes the expected
    fraction lost P (burst 1: each message lost with probability P, never two in a row)."""
    if not 0.0 <= probability < 1.0:
        raise ConfigError("loss", f"must be a probability in [0, 1), got {short(probability)}")
    if int(burst) != burst or burst < 1:
        raise ConfigError("loss_burst", f"must be an integer >= 1, got {short(burst)}")
    lost = np.zeros(samples, dtype=bool)
    if probability == 0:
        return lost
    rng = np.random.default_rng([int(seed), LOSS])
    mean = (1 + int(burst)) / 2
    q = probability / (mean * (1 - probability))
    if q >= 1:
        raise ConfigError("loss", f"{probability:g} is more than runs of up to {int(burst)} "
                                  f"lost messages can give")
    starts = rng.random(samples) < q
    lengths = rng.integers(1, int(burst) + 1, samples)
    k = 0
    while k < samples:
        if starts[k]:
            lost[k:k + lengths[k]] = True
            k += lengths[k] + 1
        else:
            k += 1
    return lost


def effort(kind: str, tau: np.ndarray, gravity: np.ndarray, friction: np.ndarray, seed: int,
           torque_noise: float = 0.0, current_noise: float = 0.0, kt=0.1, gear=100.0):
    """JointState.effort of each sample (rows) for the effort meaning ``kind``:

    - ``commanded``: the motor torque commanded, gravity compensation included (tau);
    - ``commanded_no_gravity``: tau - g(q_m), the controller's gravity term removed (as
      franka_ros2's torque command, to which the robot adds gravity);
    - ``measured``: the link-side joint torque a torque sensor gives, tau_J = tau - tau_f(v)
      (friction acts motor-side), plus Gaussian noise of ``torque_noise`` Nm;
    - ``current``: the motor current tau / (kt gear) (A), plus Gaussian noise of
      ``current_noise`` A (kt: Nm/A, gear: the ratio; per joint or one value)."""
    if kind not in EFFORTS:
        raise ConfigError("effort", f"one of {', '.join(EFFORTS)}; got {short(kind)}")
    tau = np.asarray(tau, dtype=float)
    if kind == "commanded":
        return tau.copy()
    if kind == "commanded_no_gravity":
        return tau - gravity
    if kind == "measured":
        out = tau - friction
        if torque_noise > 0:
            out = out + torque_noise * np.random.default_rng([int(seed), TORQUE_NOISE]) \
                .standard_normal(out.shape)
        return out
    ratio = np.broadcast_to(np.asarray(kt, dtype=float) * np.asarray(gear, dtype=float),
                            tau.shape[1:])
    if not np.all(np.isfinite(ratio) & (ratio > 0)):
        raise ConfigError("kt", f"kt and gear must be finite and > 0, got {short(kt)}, "
                                f"{short(gear)}")
    out = tau / ratio
    if current_noise > 0:
        out = out + current_noise * np.random.default_rng([int(seed), CURRENT_NOISE]) \
            .standard_normal(out.shape)
    return out
