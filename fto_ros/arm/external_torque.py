"""External joint torques of an arm: the adapters around the pure steps of :mod:`.steps`.

Each adapter owns a design (its constants), the restart and the calls to the model, and is
transactional: a sample it cannot use (not one finite value per joint, an absurd value, a
stamp that is not one sample period after the last) raises :class:`SampleRejected` and
leaves every state as it was; after a gap, ``reset()``. ``update(t, q, tau)`` takes the measured positions at t and the torques
commanded at t (they act until the next sample) and returns the tau_ext estimate, or None
while it has none yet; ``velocity`` is the joint-velocity estimate at the last sample.

- :class:`WindowEstimator`: the package's estimator (docs/external_torque.md): velocities
  from the robust exact differentiator, tau_ext from the windowed momentum identity, exact
  T after any change of tau_ext up to the encoder noise, whose gain it states;
- :class:`MomentumObserver`: the generalized-momentum observer (the baseline), on the
  velocities of the differentiator or of a backward difference;
- :class:`FiniteDifference`: backward differences through the inverse dynamics.
"""
from __future__ import annotations

import math

import numpy as np

from ..core import jit
from ..core.errors import FtoRosError
from . import steps
from . import steps_compiled as compiled
from .model import RigidBodyModel


def run_over(est, t, q, tau) -> tuple[np.ndarray, np.ndarray]:
    """(tau_ext estimates, velocity estimates) of a restarted ``est`` over a recording: per
    sample k the estimate after ``est.update(t[k], q[k], tau[k])`` (NaN while there is none)."""
    est.reset()
    E, V = np.full(np.shape(q), np.nan), np.zeros(np.shape(q))
    for k in range(len(t)):
        out = est.update(t[k], q[k], tau[k])
        if out is not None:
            E[k] = out
        V[k] = est.velocity
    return E, V


class SampleRejected(FtoRosError, ValueError):
    """A sample the estimator cannot use; its state is unchanged."""


class DesignRefused(FtoRosError, ValueError):
    """An estimator design that cannot be built (the message names the setting)."""


#: most memory the window estimator's ring (M and Mdot of every sample of the window) may
#: take: with the URDF's joint cap and T = 60 ms at 1 kHz, configuring stays within about
#: 200 MB (benchmarks/bench_urdf_size.py)
MAX_WINDOW_BYTES = 64 * 2 ** 20


class _Estimator:
    def __init__(self, model: RigidBodyModel, sample_period: float):
        if not (isinstance(sample_period, (int, float)) and 0 < sample_period < 1):
            raise ValueError(f"sample_period: must be in (0, 1) s, got {sample_period!r}")
        self.model, self.n, self.h = model, model.n, float(sample_period)
        self.velocity = np.zeros(self.n)
        self.tau_ext = None
        self.reset()

    def reset(self) -> None:
        """Restart at the next sample."""
        self._t = None
        self.tau_ext = None
        self._restart()

    def _inputs(self, t, q, tau):
        vectors = []
        for name, x in (("positions", q), ("torques", tau)):
            try:
                arr = np.asarray(x, dtype=float)
            except (TypeError, ValueError):
                raise SampleRejected(f"{name}: not numbers") from None
            if arr.shape != (self.n,):
                raise SampleRejected(f"{name}: need {self.n} values, got shape {arr.shape}")
            vectors.append(arr)
        if not (isinstance(t, (int, float, np.floating)) and math.isfinite(t)):
            raise SampleRejected(f"the stamp {t!r} is not a finite number")
        h = None if self._t is None else t - self._t
        if h is not None and not abs(h - self.h) <= 1e-3 * self.h:
            raise SampleRejected(f"the step {h!r} s is not the sample period {self.h!r} s "
                                 f"(within 0.1 %): restart after a gap")
        try:
            steps._check(self.h, vectors[0], vectors[1], self.n)
        except ValueError as err:
            raise SampleRejected(str(err)) from None
        return h, vectors[0], vectors[1]

    def update(self, t: float, q, tau):
        h, q, tau = self._inputs(t, q, tau)
        try:
            self._update(h, q, tau)
        except ValueError as err:
            raise SampleRejected(str(err)) from None
        self._t = float(t)
        return self.tau_ext

    def _phi(self, q, v, mass: bool = True):
        """(M, Mdot, C^T v - g - Coulomb friction) at (q, v); without M if not ``mass``."""
        M, Md, CTv, g = self.model.momentum_terms(q, v, mass)
        m = self.model
        phi = CTv - g - m.coulomb * np.tanh(v / m.friction_width)
        return (M, Md, phi) if mass else (Md, phi)


class WindowEstimator(_Estimator):
    """The windowed momentum estimator (docs/external_torque.md).

    Args:
        window: T in seconds (a whole number of sample periods, at least 8).
        velocity_order, velocity_L, velocity_rho: the differentiator of the velocities."""

    def __init__(self, model: RigidBodyModel, sample_period: float = 1e-3, window: float = 0.06,
                 velocity_order: int = 2, velocity_L: float = 300.0, velocity_rho: float = 2.0,
                 central: int = steps.CENTRAL, compiled: bool | None = None):
        W = round(window / sample_period)
        #: the steps of :mod:`.steps_compiled` (default: when numba is on), else the numpy ones
        self.compiled = jit.ENABLED if compiled is None else bool(compiled)
        if not (8 <= W <= 2000 and abs(W * sample_period - window) < 1e-9 + 1e-6 * window):
            raise DesignRefused(f"window: must be 8..2000 sample periods, got {window!r} s")
        ring = 8 * (W + 1) * (5 * model.n + 2 * model.n ** 2)
        if ring > MAX_WINDOW_BYTES:
            raise DesignRefused(f"window: {W} samples of {model.n} joints need {ring / 2 ** 20:.0f}"
                                f" MiB, more than the {MAX_WINDOW_BYTES // 2 ** 20} MiB accepted: "
                                f"a shorter window or fewer joints")
        self.samples = W
        self.window = W * sample_period
        self._red_c = steps.red_consts(velocity_order, velocity_L, velocity_rho)
        self._win_c = steps.window_consts(model.n, W, sample_period, model.viscous, central)
        self._a_norm = float(np.linalg.norm(self._win_c[4 + model.n:4 + model.n + W + 1]))
        super().__init__(model, sample_period)

    @property
    def guaranteed_time(self) -> float:
        """From a restart, the estimate exists and is exact (up to noise) after T."""
        return self.window

    def _restart(self):
        self._red = self._mass = None
        self._win = steps.window_init(self._win_c)

    def _update(self, h, q, tau):
        if self.compiled:
            return self._update_compiled(h, q, tau)
        red = steps.red_init(self._red_c, q) if h is None else \
            steps.red_step(self._red, self._red_c, h, q)
        v = steps.red_output(red, self._red_c, self.n)[:, 1].copy()
        M, Md, phi = self._phi(q, v)
        central = steps.window_central(self._win, self._win_c, q)
        Md_c = phi_c = None
        if central is not None:
            _, Md_c, phi_c = self._phi(*central)
        win = steps.window_step(self._win, self._win_c, self.h if h is None else h, q, tau,
                                M, Md, phi, Md_c, phi_c)
        self._red, self._win, self.velocity, self._mass = red, win, v, M
        out = steps.window_output(win, self._win_c)
        self.tau_ext = None if out is None else out.copy()

    def _update_compiled(self, h, q, tau):
        """The same step through :mod:`.steps_compiled` (the sample is validated)."""
        red = steps.red_init(self._red_c, q) if h is None else \
            compiled.red_step(self._red, self._red_c, h, q)
        if not np.all(np.isfinite(red)):
            raise ValueError("differentiator: the step gives a non-finite estimate")
        v = steps.red_output(red, self._red_c, self.n)[:, 1].copy()
        M, Md, phi = self._phi(q, v)
        has_c = self._win[0] >= 2 * self._win_c[3]
        Md_c, phi_c = Md, phi
        if has_c:
            Md_c, phi_c = self._phi(*compiled.window_central(self._win, self._win_c, q),
                                    mass=False)
        win = np.empty_like(self._win)
        if not compiled.window_step(self._win, self._win_c, q, tau, M, Md, phi, Md_c, phi_c,
                                    has_c, win):
            raise ValueError("window: a model term or the estimate is not finite")
        self._red, self._win, self.velocity, self._mass = red, win, v, M
        out = steps.window_output(win, self._win_c)
        self.tau_ext = None if out is None else out.copy()

    def noise_gain(self, q=None) -> np.ndarray:
        """Per joint, the standard deviation of the estimate per unit (rad) of white encoder
        noise at the configuration q (None: the last sample's): ||a|| ||M_i,:|| (the kernel's
        second-derivative weights, docs/external_torque.md)."""
        M = self._mass if q is None else self.model.mass_matrix(q)
        return self._a_norm * np.sqrt(np.einsum("ij,ij->i", M, M))

    def step_response(self, elapsed: float) -> float:
        """Fraction of a step of tau_ext shown ``elapsed`` s after it: K(elapsed / T)."""
        s = min(max(elapsed / self.window, 0.0), 1.0)
        return float(steps.kernel(s, -1))


class MomentumObserver(_Estimator):
    """The generalized-momentum observer with gain K_O (1/s) on every joint, fed the
    velocities of the differentiator (``velocity='differentiator'``) or of a backward
    difference (``'difference'``)."""

    def __init__(self, model: RigidBodyModel, sample_period: float = 1e-3, gain: float = 50.0,
                 velocity: str = "difference", velocity_order: int = 2, velocity_L: float = 300.0,
                 velocity_rho: float = 2.0):
        if velocity not in ("difference", "differentiator"):
            raise ValueError(f"velocity: 'difference' or 'differentiator', got {velocity!r}")
        g = np.broadcast_to(np.asarray(gain, dtype=float), (model.n,)).copy()
        if not np.all(np.isfinite(g) & (g > 0)):
            raise ValueError(f"gain: must be finite and > 0, got {gain!r}")
        self.gain, self.source = g, velocity
        self._red_c = steps.red_consts(velocity_order, velocity_L, velocity_rho)
        super().__init__(model, sample_period)

    guaranteed_time = math.inf

    def _restart(self):
        self._vel = None
        self._gmo = steps.gmo_init(self.n)

    def _update(self, h, q, tau):
        if self.source == "differentiator":
            vel = steps.red_init(self._red_c, q) if h is None else \
                steps.red_step(self._vel, self._red_c, h, q)
            v = steps.red_output(vel, self._red_c, self.n)[:, 1].copy()
        else:
            vel = steps.fd_init(self.n) if h is None else self._vel
            v, _ = steps.fd_velocity(vel, self.h if h is None else h, q)
            # fd_step keeps the past positions (its own estimate is not used here)
            vel = steps.fd_step(vel, self.h if h is None else h, q, tau, np.zeros(self.n))
        M, _, CTv, g = self.model.momentum_terms(q, v)
        beta = CTv - g - self.model.friction(v)
        gmo = steps.gmo_step(self._gmo, self.gain, self.h if h is None else h, q, tau, M @ v, beta)
        self._vel, self._gmo, self.velocity = vel, gmo, v
        self.tau_ext = steps.gmo_output(gmo, self.n).copy() if h is not None else None


class FiniteDifference(_Estimator):
    """tau_ext = M a + C v + g + tau_f - tau with v, a backward differences."""

    guaranteed_time = math.inf

    def _restart(self):
        self._fd = steps.fd_init(self.n)

    def _update(self, h, q, tau):
        ready = self._fd[0] >= 2                  # q_(k-1), q_(k-2) and tau_(k-1) are in
        hh = self.h if h is None else h
        v, a = steps.fd_velocity(self._fd, hh, q)
        fd = steps.fd_step(self._fd, hh, q, tau, self.model.inverse_dynamics(q, v, a))
        self._fd, self.velocity = fd, v
        self.tau_ext = steps.fd_output(fd, self.n).copy() if ready else None
