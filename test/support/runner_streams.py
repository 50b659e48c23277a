"""The runner tests' DC motor (test/unit/runner/test_runner*.py): its configurations (the
pole-placement Luenberger and single_delay, continuous and sampled), the simulated streams
(``uniform_stream``: q and V at 1 kHz; ``sparse_stream``: q at irregular 1-2 ms instants),
feeding a runner event by event (``drive``) and comparing outputs bit for bit.

The stream is the paper's DC-motor manipulator (Mazenc & Malisoff 2022, eq. 65) simulated
with the ZOH simulator.
"""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate, uniform_grid
from fto_ros.runner import Output, Runner, load_params_file
from fto_ros.runner.runner import HELD

ROOT = Path(__file__).resolve().parents[2]
# the pole-placement Luenberger: its poles make the runner tests' expectations exact
CONFIG = {name: load_params_file(ROOT / "test" / "data" / "dc_motor_explicit" / f"dc_motor_{file}.yaml")
          for name, file in (("luenberger", "luenberger_poles"), ("single_delay", "single_delay"),
                             ("single_delay_sampled", "single_delay_sampled"))}
CONTINUOUS = ("luenberger", "single_delay")
NAN, INF = float("nan"), float("inf")

_TEMPLATES: dict = {}


def flat(name: str, **changes) -> dict:
    """The config ``name`` with changes (``a__b=v`` for ``a.b``; None removes the key)."""
    out = dict(CONFIG[name])
    for k, v in changes.items():
        k = k.replace("__", ".")
        if v is None:
            out.pop(k, None)
        else:
            out[k] = v
    return out


def make(name: str, **changes) -> Runner:
    """A fresh Runner (built once per configuration, then deep-copied: single_delay's design is slow)."""
    key = (name, repr(sorted(changes.items())))
    if key not in _TEMPLATES:
        _TEMPLATES[key] = Runner(flat(name, **changes))
    return copy.deepcopy(_TEMPLATES[key])


# -- streams --------------------------------------------------------------------------------------
class Stream:
    """Measurements (t, y, x true) and inputs (t_u, u) with an event order."""

    def __init__(self, t, y, x, t_u, u):
        self.t, self.y, self.x, self.t_u, self.u = t, y, x, t_u, u
        ev = [(tt, 0, i) for i, tt in enumerate(t_u)] + [(tt, 1, i) for i, tt in enumerate(t)]
        self.events = sorted(ev)          # an input at the same stamp comes first
        # position in events right after measurement i
        self.after = {i: n + 1 for n, (_, kind, i) in enumerate(self.events) if kind == 1}


def uniform_stream() -> Stream:
    """1 s of the DC motor, q measured and V given at 1 kHz."""
    t = uniform_grid(1.0, 1000.0)
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage,
                   output=dc_motor.output)
    return Stream(t, sim.y, sim.x, sim.t_u, sim.u_k)


def sparse_stream() -> Stream:
    """0.6 s of the DC motor, q at irregular 1-2 ms instants, V at 1 kHz."""
    # irregular gaps in [1, 2] ms on a 0.1 ms clock: few distinct step sizes, so the expm cache
    # works (with arbitrary nanosecond gaps nearly every sub-step costs an expm)
    gaps = np.random.default_rng(2022).integers(10, 21, size=400) * 100_000
    t = np.concatenate(([0], np.cumsum(gaps)))
    t = t[t <= 600_000_000] / 1e9
    t_in = uniform_grid(0.6, 1000.0)
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage,
                   t_input=t_in, output=dc_motor.output)
    return Stream(t, sim.y, sim.x, sim.t_u, sim.u_k)


def stream_for(name, uniform, sparse):
    return sparse if name == "single_delay_sampled" else uniform


def drive(r: Runner, s: Stream, lo: int = 0, hi: int | None = None,
          held_first: bool = False) -> dict[int, Output]:
    """Feed measurements lo..hi-1 (and the inputs between them): {measurement index: Output}.
    ``held_first``: measurement lo is after a time discontinuity, held until the next
    confirms it (no Output for it)."""
    hi = len(s.t) if hi is None else hi
    start = 0 if lo == 0 else s.after[lo - 1]
    end = s.after[hi - 1]             # the inputs after measurement hi-1 belong to the next call
    outs = {}
    for t, kind, i in s.events[start:end]:
        if kind == 0:
            assert r.set_input(t, s.u[i]) is None
        else:
            out = r.process(t, s.y[i])
            if held_first and i == lo:
                assert out == HELD, f"sample {i} at {t}: {out}"
                continue
            assert isinstance(out, Output), f"sample {i} at {t}: {out}"
            outs[i] = out
    return outs


def check_finite(out: Output):
    assert np.all(np.isfinite(out.estimate))
    assert np.all(np.isfinite(out.convergence[[0, 1, 2, 4]]))
    assert out.unknown_input is None or np.all(np.isfinite(out.unknown_input))
    if out.joint_state is not None:
        for field in out.joint_state[1:]:
            assert all(math.isfinite(v) for v in field)


def same_output(a: Output, b: Output):
    assert a.t == b.t
    np.testing.assert_array_equal(a.estimate, b.estimate)
    np.testing.assert_array_equal(a.convergence, b.convergence)
    assert a.joint_state == b.joint_state


_CLEAN: dict = {}


def clean(name, s: Stream) -> dict[int, Output]:
    key = (name, id(s))
    if key not in _CLEAN:
        _CLEAN[key] = drive(make(name), s)
    return _CLEAN[key]


def single_delay_run(n: int = 300) -> dict[str, np.ndarray]:
    """What test_runner_is_deterministic compares between two processes: a fresh
    single_delay runner's outputs on the first ``n`` measurements of ``uniform_stream``."""
    outs = drive(make("single_delay"), uniform_stream(), 0, n)
    keys = sorted(outs)
    return {"index": np.array(keys), "t": np.array([outs[i].t for i in keys]),
            "estimate": np.array([outs[i].estimate for i in keys]),
            "convergence": np.array([outs[i].convergence for i in keys])}


@pytest.fixture(scope="module")
def uniform() -> Stream:
    """The fixture of ``uniform_stream`` (import it into a test module to use it)."""
    return uniform_stream()


@pytest.fixture(scope="module")
def sparse() -> Stream:
    """The fixture of ``sparse_stream``."""
    return sparse_stream()
