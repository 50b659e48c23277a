"""The observer protocol and the parameter schema every observer declares.

ROS-free.  An observer is built from a dict of already-typed parameter values
(keyed by the short names of its ``PARAMS``) and is then driven sample by
sample with ``update(t, y, u)``.  The runner wraps it; the node and the replay
harness only ever talk to the runner.
"""
from __future__ import annotations

import abc
import math
from typing import Any

import numpy as np

from ..core.discretize import STEP_QUANTUM
# an observer family imports what it declares and raises from here (the schema itself is
# core/params.py's, shared with the plant block and the runner)
from ..core.errors import ConfigError, SampleRejected  # noqa: F401 (ConfigError)
from ..core.params import Param, check_vector, matrix  # noqa: F401
from ..core.reasons import REJECTIONS


class Observer(abc.ABC):
    """Sample-driven, variable-step state observer: the protocol every observer keeps.

    Subclasses set ``TYPE`` (the registry name) and ``PARAMS``; every family is a
    ``KernelObserver`` below (a compiled per-sample kernel, observers/kernel.py).  Times are
    seconds (float), ``y`` has length ``n_outputs``, ``u`` length ``n_inputs`` (an empty
    array when there is no known input).  ``u`` given at time t is the input applied from t
    on (zero-order hold, like a DAC) unless the observer's ``input_hold`` says first-order
    hold.

    **Time is owned by the kernel protocol.**  observers/kernel.py counts the observer's
    clock in whole STEP_QUANTUM (1 us) since the first sample after the last ``reset`` and
    hands the family a step ``h`` that is a positive multiple of the quantum and at most
    ``max_step``; the family integrates that interval and nothing else.  The runner
    (runner/) classifies every interval before it gets there (repeated, backward, a gap
    longer than ``max_step`` or ``time.max_gap`` restarts), so on valid input an observer
    never raises anything but SampleRejected for a value its model cannot use.
    """

    TYPE: str = ""
    PARAMS: tuple[Param, ...] = ()
    DESCRIPTION: str = ""
    #: a composition's parameters that name the observers it is made of (observers/track/);
    #: registry.make hands a composition itself, to build them
    CHILD_ROLES: tuple[str, ...] = ()

    n_states: int
    n_outputs: int
    n_inputs: int
    state_names: list[str]

    # -- life cycle ---------------------------------------------------------------------
    @abc.abstractmethod
    def reset(self, t0: float | None = None, x0_hat: np.ndarray | None = None) -> None:
        """Restart at the next sample; ``x0_hat`` is the initial estimate there (None:
        the observer's default).  ``t0`` is accepted for compatibility and unused: the
        clock restarts at the next sample's stamp."""

    def update(self, t: float, y, u) -> None:
        """Take the sample y measured at t with the current input u.

        Either commits a new, finite state or raises SampleRejected and leaves
        the state as it was.  y and u are checked here (length, finite); the
        runner checks them once itself and calls ``update_checked``.
        """
        reason = (check_vector(y, self.n_outputs, "measurement")
                  or check_vector(u, self.n_inputs, "input"))
        if reason is not None:
            raise SampleRejected(reason)
        self.update_checked(t, np.asarray(y, dtype=float), np.asarray(u, dtype=float))

    @abc.abstractmethod
    def update_checked(self, t: float, y: np.ndarray, u: np.ndarray) -> None:
        """``update`` for a y and u already checked (float arrays of the right length,
        finite)."""

    @property
    @abc.abstractmethod
    def started(self) -> bool:
        """Whether a sample was accepted since the last reset."""

    @property
    @abc.abstractmethod
    def time_since_start(self) -> float:
        """Model time of the last accepted sample since the (re)start (s)."""

    @property
    def max_step(self) -> float:
        """The longest interval this observer bridges exactly with bounded work (s);
        a longer one is a gap the runner restarts it at."""
        return math.inf

    # -- outputs --------------------------------------------------------
    @property
    @abc.abstractmethod
    def estimate(self) -> np.ndarray:
        """x-hat at the time of the last update, in the plant's own coordinates."""

    @property
    def unknown_input(self) -> np.ndarray | None:
        """Estimate of the unknown input, for observers that identify it."""
        return None

    @property
    def has_unknown_input(self) -> bool:
        """Whether this observer identifies an unknown input (publishes its estimate)."""
        return type(self).unknown_input is not Observer.unknown_input

    @property
    def guaranteed_time(self) -> float:
        """Time after reset from which the estimate is guaranteed (inf: none, the default)."""
        return math.inf

    #: the output residual of the last update, kept by the observer (nan before one)
    _residual: float = math.nan

    @property
    def output_residual(self) -> float:
        """Norm of the one-step output prediction error at the last update."""
        return self._residual

    @property
    def health(self) -> float:
        """The observer-specific health figure published on ``convergence``."""
        return float("nan")

    @property
    def converged(self) -> bool | None:
        """Whether the estimate has converged, for an observer that knows it better than the
        runner's rule (guaranteed time reached, else residual below the threshold); None:
        the runner's rule."""
        return None

    #: labels of observer-specific values published on ``convergence`` after the common ones
    CONVERGENCE_EXTRA: tuple[str, ...] = ()

    def convergence_extra(self) -> tuple[float, ...]:
        """The values labelled by CONVERGENCE_EXTRA (finite)."""
        return ()

    #: what ``health`` is, for the docs and the diagnostics
    HEALTH_NAME: str = ""

    def diagnostics(self) -> dict[str, Any]:
        """Observer-specific key-values for /diagnostics (human-readable)."""
        return {}


class RestartCovariance:
    """A Kalman filter whose (re)start covariance lives in its constants (``_p0()``: a view
    of n x n floats there): ``P0`` reads a copy and assigning sets it, as ``track`` does at
    every hand-over (a tracker provides this, its ``R`` and its NIS as st[HEALTH]).  The
    class defines ``_p0``."""

    @property
    def P0(self) -> np.ndarray:
        """The covariance every (re)start begins with (a copy; assign to change it)."""
        return self._p0().copy()

    @P0.setter
    def P0(self, value) -> None:
        self._p0()[:] = np.asarray(value, dtype=float).reshape(self._p0().shape)


class KernelObserver(Observer):
    """An observer family as a compiled per-sample kernel (observers/kernel.py) plus this
    adapter: the subclass designs and builds the kernel's constants and work memory once
    (``_build_kernel``); everything per sample goes through the kernel, here as in the
    runner's block loop.  ``update`` and ``reset`` keep the observer protocol for callers that
    drive an observer directly (the paper tests); the runner hands ``program()`` to its
    compiled loop."""

    #: the kernel module: its ``kernel(op, ...)`` function
    KERNEL = None

    def _build_kernel(self, c, ic, wk, state_size: int, models=()) -> None:
        from ..core import jit as J
        from ..core.model_code import none_kernel
        from . import kernel as K
        self._K = K
        self._c = np.ascontiguousarray(c, dtype=float)
        self._ic = np.ascontiguousarray(ic, dtype=np.int64)
        self._wk = np.ascontiguousarray(wk, dtype=float)
        self._st = np.zeros(int(state_size))
        self._nx = np.zeros(int(state_size))
        self._st[K.RESIDUAL] = math.nan
        self._st[K.CONVERGED] = -1.0
        self._st[K.GUARANTEED] = math.inf
        self._clk = np.array([math.nan, 0.0, math.nan])
        self.models = list(models)
        self._kernels = J.function_list([J.kernel(self.KERNEL.kernel, J.KERNEL)], J.KERNELS)
        slots = self.models + [None] * (J.MODEL_SLOTS - len(self.models))
        self._models = J.function_list([none_kernel() if m is None else m.kernel for m in slots],
                                       J.MODELS)
        self._empty = np.zeros(0)

    #: what a copy shares with the original: compiled functions, model terms, modules
    _SHARED = ("_kernels", "_models", "models", "_K")

    def __deepcopy__(self, memo):
        import copy
        new = object.__new__(type(self))
        memo[id(self)] = new
        for k, v in self.__dict__.items():
            new.__dict__[k] = v if k in self._SHARED else copy.deepcopy(v, memo)
        return new

    # -- the protocol, through the kernel ---------------------------------------------
    def _restart(self, x0_hat):
        """Forget the run: the next sample starts a new one from ``x0_hat`` (None: the
        family's default)."""
        has = x0_hat is not None
        x0 = np.ascontiguousarray(x0_hat, dtype=float) if has else self._empty
        self._K.restart(self._kernels, self._models, self._st, self._nx, self._c, self._ic,
                        self._wk, self._clk, x0, has, False)

    def reset(self, t0=None, x0_hat=None) -> None:
        self._restart(None if x0_hat is None else np.array(x0_hat, dtype=float))

    def update_checked(self, t, y, u) -> None:
        code = self._K.update(self._kernels, self._models, self._st, self._nx, self._c,
                              self._ic, self._wk, self._clk, float(t),
                              np.ascontiguousarray(y, dtype=float),
                              np.ascontiguousarray(u, dtype=float))
        if code:
            raise SampleRejected(REJECTIONS[code])

    def advance(self, t, u) -> None:
        """Integrate to t with the new input u (families that predict between samples)."""
        code = self._K.advance(self._kernels, self._models, self._st, self._nx, self._c,
                               self._ic, self._wk, self._clk, float(t),
                               np.ascontiguousarray(u, dtype=float), self._empty)
        if code:
            raise SampleRejected(REJECTIONS[code])

    @property
    def has_advance(self) -> bool:
        return bool(self._ic[self._K.HAS_ADVANCE])

    # -- what the state says ----------------------------------------------------------
    @property
    def started(self) -> bool:
        return not math.isnan(self._clk[0])

    @property
    def time_since_start(self) -> float:
        return self._clk[1] * STEP_QUANTUM

    @property
    def max_step(self) -> float:
        return float(self._c[self._K.MAX_STEP])

    @property
    def estimate(self) -> np.ndarray:
        o, n = self._ic[self._K.EST], self._ic[self._K.N_STATES]
        return self._st[o:o + n]

    @property
    def has_unknown_input(self) -> bool:
        return bool(self._ic[self._K.N_UI])

    @property
    def unknown_input(self):
        n = self._ic[self._K.N_UI]
        if n == 0:
            return None
        o = self._ic[self._K.UI]
        return self._st[o:o + n]

    @property
    def output_residual(self) -> float:
        return float(self._st[self._K.RESIDUAL])

    @property
    def health(self) -> float:
        return float(self._st[self._K.HEALTH])

    @property
    def guaranteed_time(self) -> float:
        return float(self._st[self._K.GUARANTEED])

    @property
    def converged(self):
        v = self._st[self._K.CONVERGED]
        return None if v < 0 else bool(v)

    def convergence_extra(self) -> tuple[float, ...]:
        o, n = self._ic[self._K.EXTRA], self._ic[self._K.N_EXTRA]
        return tuple(self._st[o:o + n].tolist())

    def adopt(self, st, nx, c, ic, wk, clk) -> None:
        """Use these arrays (rows of the runner's arrays of every joint) as the observer's
        memory from now on; they hold the same values as its own."""
        self._st, self._nx, self._c, self._ic, self._wk, self._clk = st, nx, c, ic, wk, clk

    def program(self):
        """What the runner's block loop takes: (kernels, models, state, candidate, consts,
        integer consts, work, clock)."""
        return (self._kernels, self._models, self._st, self._nx, self._c, self._ic, self._wk,
                self._clk)
