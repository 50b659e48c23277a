"""The compiled acquire-then-track composition (observers/track/ adapter.py and kernel.py,
built by observers/registry.py ``make``), against a plain-Python statement of its rules.

What is checked:
- its decisions, sample by sample, against ``RulesInPython`` below (the rules of design.py
  written as per-sample Python over the same compiled children): every output equal bit for
  bit through hand-overs by the guaranteed time or by the certificate, re-acquisitions, a
  restart from a given estimate and samples the children reject; with a test-only compiled
  acquirer (a luenberger kernel claiming a guaranteed time) and with a global_norm acquirer
  whose observability form is reached through a constant map (``global_norm.chain_map``:
  the acquirer publishes plant coordinates, so the composition hands the tracker the
  plant-coordinate estimate);
- through the runner's compiled block loop (a block and one event at a time alike, copies,
  several joints) the outputs of the observer driven directly; the mapped acquirer's track
  runs there (once on the previous Python runner: now compiled) and converges to the plant's
  state in its own coordinates;
- the window's exact sum is math.fsum; a composition that never decides is stopped.
"""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core import jit as J
from fto_ros.core.discretize import STEP_QUANTUM, quanta
from fto_ros.core.params import resolve
from fto_ros.core.reasons import CODE
from fto_ros.models.simulate import simulate
from fto_ros.observers import REGISTRY, kernel as K, make
from fto_ros.observers.base import SampleRejected
from fto_ros.observers.luenberger import LuenbergerObserver
from fto_ros.observers.track import TrackObserver, kernel as TK
from fto_ros.observers.track.design import ACQUIRING, REACQUIRING, TRACKING
from fto_ros.runner import Output, Runner
from fto_ros.runner import loop as L
from fto_ros.runner import settings as S
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parents[3]
CONFIG = ROOT / "config"
PLANT = CONFIG / "dc_motor_plant.yaml"


class _GuaranteedLuenberger(LuenbergerObserver):
    """Test-only acquirer: a compiled kernel claiming a guaranteed time of 0.1 s (luenberger
    is not an acquirer of the package: it guarantees nothing)."""

    def __init__(self, cfg):
        super().__init__(cfg)
        self._st[K.GUARANTEED] = 0.1


def _stand_in_make(guaranteed: bool):
    """``make`` with the acquirer's type (single_delay) built as the luenberger kernel."""
    acquirer = _GuaranteedLuenberger if guaranteed else LuenbergerObserver

    def build(type_name, cfg):
        return acquirer(cfg) if type_name == "single_delay" else make(type_name, cfg)
    return build


def _section(name: str):
    _, _, cfg = S.split(load_params_files([str(PLANT), str(CONFIG / name)]))
    return cfg


def _composition_cfg(tracker: str) -> dict:
    cfg = resolve(TrackObserver.PARAMS, {"acquirer": "single_delay", "tracker": tracker},
                  prefix="track.")
    cfg["acquirer_observer"] = ("single_delay", _section("dc_motor_luenberger_poles.yaml"))
    cfg["tracker_observer"] = (tracker, _section("dc_motor_ekf.yaml" if tracker == "ekf"
                                                 else "dc_motor_luenberger.yaml"))
    return cfg


def _stream(seed: int = 1, n: int = 4000):
    """Noisy DC-motor samples with a 0.3 rad jump of the measurement at 2.5 s (a slipped
    encoder: the tracker becomes inconsistent and re-acquires, again and again)."""
    from fto_ros.models import dc_motor
    t = np.arange(n) * 1e-3
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage)
    y = sim.x[:, :1] + 1e-3 * np.random.default_rng(seed).standard_normal((n, 1))
    y[2500:, 0] += 0.3
    return t, y, sim.u


# -- a plant whose observability form is reached through a map: y = 2 x ---------------------
MAPPED_PLANT = {"plant.states": ["x", "v"], "plant.inputs": ["F"],
                "plant.constants": ["m=0.5", "c=1.0", "k=8.0", "k3=40.0"],
                "plant.f": ["v", "(F - c*v - k*x - k3*x**3)/m"], "plant.h": ["2*x"]}


def _mapped_flat() -> dict:
    flat = dict(MAPPED_PLANT)
    flat.update({"observer.type": "track", "track.acquirer": "global_norm",
                 "track.tracker": "ekf", "track.certificate_samples": 20,
                 "global_norm.conditions": "warn", "global_norm.gamma_hat": "10 + 10*w",
                 "ekf.process_noise": [1e-8, 1.0], "ekf.measurement_noise": [4e-10],
                 "ekf.initial_covariance": [1e-4, 1.0]})
    return flat


def _mapped_stream(n: int = 6000, seed: int = 3):
    """The mapped plant under a known force, y = 2 x with 20 um noise, a 5 cm jump of y at
    3 s; (t, y, u, x)."""
    t = np.arange(n) * 1e-3

    def rhs(_, x, u):
        return np.array([x[1], (u[0] - x[1] - 8 * x[0] - 40 * x[0] ** 3) / 0.5])
    sim = simulate(rhs, [0.5, 1.0], t, lambda s: [2 * math.sin(1.5 * s) + 1.5 * math.sin(4.1 * s)])
    y = 2 * sim.x[:, :1] + 2e-5 * np.random.default_rng(seed).standard_normal((n, 1))
    y[3000:, 0] += 0.05
    return t, y, sim.u, sim.x


# -- the rules in plain Python ----------------------------------------------------------------
class RulesInPython:
    """design.py's rules as per-sample Python, driving its own children (built like the
    composition's) through their protocol; its constants (threshold, clip, certificate,
    hand-over covariance) are those of ``design``, a composition of the same config."""

    def __init__(self, design: TrackObserver, cfg: dict, make_child):
        self.d = design
        self.acquirer = make_child(*cfg["acquirer_observer"])
        self.tracker = copy.deepcopy(design.tracker)
        self.max_step = min(self.acquirer.max_step, self.tracker.max_step)
        self.handovers = self.reacquisitions = 0
        self.reset(None)

    def reset(self, x0):
        self.acquirer.reset(None, x0)
        self.tracker.reset(None)
        self.mode, self.run_handovers, self.run_reacquisitions, self.quiet = ACQUIRING, 0, 0, 0
        self.nis: list[float] = []
        self.nis_sum = 0.0
        self.t0, self.k = None, 0

    def update_checked(self, t, y, u):
        if self.t0 is not None:                       # the composition's own clock
            k = quanta(t - self.t0)
            if k <= self.k:
                raise SampleRejected("stamp_too_close")
            if (k - self.k) * STEP_QUANTUM > self.max_step:
                raise SampleRejected("step_too_long")
        self._sample(t, y, u)
        if self.t0 is None:
            self.t0, self.k = t, 0
        else:
            self.k = quanta(t - self.t0)

    def _sample(self, t, y, u):
        if self.mode == ACQUIRING:
            self.acquirer.update_checked(t, y, u)     # a rejection leaves both untouched
            self._acquired(t, y, u)
            return
        self.tracker.update_checked(t, y, u)
        if self.mode == REACQUIRING:
            try:
                self.acquirer.update_checked(t, y, u)
            except SampleRejected:
                self.acquirer.reset(None)             # acquire afresh from the next sample
                return
            self._acquired(t, y, u)
            return
        v = self.tracker.nis
        v = min(v, self.d.clip) if math.isfinite(v) else self.d.clip
        self.nis.append(v)
        self.nis_sum += v
        if len(self.nis) > self.d.window:
            self.nis_sum -= self.nis.pop(0)
        elif len(self.nis) == self.d.window:
            self.nis_sum = math.fsum(self.nis)
        if len(self.nis) == self.d.window and self.nis_sum > self.d.threshold:
            self.reacquisitions += 1
            self.run_reacquisitions += 1
            self.mode, self.quiet = REACQUIRING, 0
            self.nis, self.nis_sum = [], 0.0
            self.acquirer.reset(None)
            self.acquirer.update_checked(t, y, u)

    def _acquired(self, t, y, u):
        a = self.acquirer
        if math.isfinite(a.guaranteed_time):
            ready = a.time_since_start >= a.guaranteed_time - 1e-9
        else:
            res = a.output_residual
            self.quiet = self.quiet + 1 if math.isfinite(res) and \
                res <= self.d.certificate_residual else 0
            ready = self.quiet >= self.d.certificate_samples
        if not ready:
            return
        self.tracker.reset(None, np.array(a.estimate, dtype=float))
        try:
            self.tracker.update_checked(t, y, u)
        except SampleRejected:
            self.tracker.reset(None)
            self.mode = ACQUIRING
            return
        self.handovers += 1
        self.run_handovers += 1
        self.mode = TRACKING
        self.nis, self.nis_sum = [], 0.0

    def outputs(self):
        shown = self.acquirer if self.mode == ACQUIRING else self.tracker
        health = self.nis_sum / self.d.threshold if self.mode == TRACKING and self.nis else 0.0
        return (shown.estimate.tolist(), shown.output_residual, health,
                self.mode == TRACKING, self.acquirer.guaranteed_time,
                (float(self.mode), float(self.run_handovers), float(self.run_reacquisitions)))


def _outputs(obs):
    return (obs.estimate.tolist(), obs.output_residual, obs.health, obs.converged,
            obs.guaranteed_time, obs.convergence_extra())


def _same_decisions(compiled, python, t, y, u, x0, x1):
    """Run both over the stream (a restart from x1 at 3/4 of it, now and then a stamp too
    close); every output equal at every sample.  The modes seen."""
    compiled.reset(None, x0)
    python.reset(x0)
    modes = set()
    for k in range(len(t)):
        if k == 3 * len(t) // 4:
            compiled.reset(None, x1)
            python.reset(x1)
        tk = t[k] if k % 500 != 7 else t[k - 1]
        got = []
        for obs in (compiled, python):
            try:
                obs.update_checked(tk, y[k], u[k])
                got.append(None)
            except SampleRejected as e:
                got.append(e.reason)
        assert got[0] == got[1], k
        assert repr(_outputs(compiled)) == repr(python.outputs()), k
        modes.add(compiled.convergence_extra()[0])
    assert compiled.diagnostics()["hand-overs"] == str(python.handovers)
    assert compiled.diagnostics()["re-acquisitions"] == str(python.reacquisitions)
    return modes


@pytest.mark.parametrize("guaranteed, tracker", [(True, "ekf"), (False, "ekf"),
                                                 (True, "luenberger")])
def test_the_composition_decides_as_the_rules_in_python(guaranteed, tracker):
    cfg = _composition_cfg(tracker)
    build = _stand_in_make(guaranteed)
    compiled = TrackObserver(cfg, build)
    python = RulesInPython(TrackObserver(cfg, build), cfg, build)
    t, y, u = _stream()
    modes = _same_decisions(compiled, python, t, y, u, [1.0, 5.0, 0.0], [0.5, -2.0, 1.0])
    assert modes == {0.0, 1.0, 2.0}
    assert python.reacquisitions >= 2


def test_a_mapped_acquirer_decides_as_the_rules_in_python():
    """global_norm on y = 2 x runs on z = T x: the composition reads the acquirer's
    published (plant-coordinate) estimate at the hand-over, as the Python rules do."""
    _, _, cfg = S.split(_mapped_flat())
    acq_type, acq_cfg = cfg["acquirer_observer"]
    assert acq_type == "global_norm" and acq_cfg["chain_map"] == [2.0, 0.0, 0.0, 2.0]
    compiled = make("track", cfg)
    assert type(compiled) is TrackObserver
    python = RulesInPython(make("track", cfg), cfg, make)
    t, y, u, _ = _mapped_stream()
    modes = _same_decisions(compiled, python, t, y, u, [0.3, -1.0], [0.1, 2.0])
    assert modes == {0.0, 1.0, 2.0}


def test_a_mapped_acquirer_runs_compiled_in_the_runner():
    """The track of a mapped global_norm acquirer in the runner's compiled loop (it ran on
    the previous Python runner): the outputs of the composition driven directly, the
    acquirer's initial estimate taken in plant coordinates, and the plant's state tracked."""
    flat = dict(_mapped_flat(), **{"observer.initial_estimate": [0.3, -1.0]})
    runner = Runner(flat)
    assert type(runner.observer) is TrackObserver
    direct = make("track", runner.observer_config)
    direct.reset(None, [0.3, -1.0])
    t, y, u, x = _mapped_stream()
    err = np.full(x.shape, np.nan)
    for k in range(len(t)):
        runner.set_input(t[k], u[k])
        out = runner.process(t[k], y[k])
        if not isinstance(out, Output):
            assert out == "outlier", (k, out)         # the runner's gate, not the observer
            continue
        direct.update_checked(t[k], y[k], u[k])
        np.testing.assert_array_equal(out.estimate, direct.estimate)
        np.testing.assert_array_equal(out.convergence[5:], direct.convergence_extra())
        if k == 0:
            np.testing.assert_allclose(out.estimate, [0.3, -1.0], rtol=1e-12)
        err[k] = np.abs(out.estimate - x[k])
    # measured: hand-over at sample 109, |x error| <= 3.6e-5 m and |v error| <= 0.050 m/s
    # from 100 samples on; the 5 cm jump of y (2.5 cm of x) re-acquires at 3006 and hands
    # over again at 3082, the estimate then following the shifted measurement
    diag = runner.observer.diagnostics()
    assert (diag["hand-overs"], diag["re-acquisitions"]) == ("2", "1"), diag
    before = np.nanmax(err[200:3000], axis=0)
    assert np.all(before < [1e-4, 0.1]), before
    shifted = np.nanmax(np.abs(err[4000:, 0] - 0.025))
    assert shifted < 1e-4, shifted


def _stand_in_flat(monkeypatch) -> dict:
    """The DC motor's track with the test-only acquirer registered as single_delay (its
    luenberger section as the plant block derives it) and the ekf as tracker."""
    monkeypatch.setitem(REGISTRY, "single_delay", _GuaranteedLuenberger)
    flat = load_params_files([str(PLANT), str(CONFIG / "dc_motor_ekf.yaml")])
    flat.update({"luenberger." + k: v for k, v in _section("dc_motor_luenberger_poles.yaml").items()})
    flat.update({"observer.type": "track", "track.acquirer": "single_delay",
                 "track.tracker": "ekf"})
    return flat


def test_the_composition_runs_in_the_runner(monkeypatch):
    """Through Runner (its compiled block loop, a block and one event at a time alike): the
    outputs of the observer driven sample by sample; a copy of the runner goes on as the
    original."""
    flat = _stand_in_flat(monkeypatch)
    runner, block_runner = Runner(flat), Runner(flat)
    assert type(runner.observer) is TrackObserver
    direct = make("track", runner.observer_config)
    direct.reset()
    t, y, u = _stream(seed=2, n=3000)
    kind = np.tile(np.array([L.INPUT, L.MEASUREMENT], np.int8), len(t))
    blk = block_runner.process_block(kind, np.repeat(t, 2),
                                     np.stack([u[:, 0], y[:, 0]], axis=1).reshape(-1, 1))
    twin, gated = None, 0
    for k in range(len(t)):
        if k == 2000:
            twin = copy.deepcopy(runner)
        outs = []
        for r in (runner, twin) if twin is not None else (runner,):
            r.set_input(t[k], u[k])
            outs.append(r.process(t[k], y[k]))
        out = outs[0]
        assert blk.status[2 * k + 1, 0] == (L.OUTPUT if isinstance(out, Output)
                                            else CODE[out]), k
        if not isinstance(out, Output):               # the outlier gate: the jump
            assert out == "outlier", (k, out)
            gated += 1
            continue
        direct.update_checked(t[k], y[k], u[k])
        np.testing.assert_array_equal(out.estimate, direct.estimate)
        np.testing.assert_array_equal(blk.estimate[2 * k + 1, 0], out.estimate)
        np.testing.assert_array_equal(blk.convergence[2 * k + 1, 0], out.convergence)
        assert out.convergence[5:].tolist() == list(direct.convergence_extra())
        if len(outs) > 1:
            np.testing.assert_array_equal(outs[1].convergence, out.convergence)
    assert gated and runner.observer.diagnostics()["mode"] in ("tracking", "re-acquiring")
    np.testing.assert_array_equal(twin.observer.estimate, runner.observer.estimate)
    assert max(blk.convergence[:, 0, 6]) >= 1                      # hand-overs


def test_the_composition_runs_per_joint(monkeypatch):
    """Three joints' compositions in one runner (the joints axis: the runner's rows of
    every array, each joint's model list its own): each joint's outputs are those of a
    runner of that joint alone, bit for bit, through its hand-over."""
    flat = _stand_in_flat(monkeypatch)
    multi = Runner(dict(flat, joints=["j1", "j2", "j3"], source="joint_states"))
    alone = [Runner(flat) for _ in range(3)]
    assert multi.n_joints == 3 and type(multi.observer) is TrackObserver
    t, y, u = _stream(seed=5, n=1500)
    ys = y + np.array([0.0, 0.01, -0.02])            # three joints, three measurements
    for k in range(len(t)):
        outs = multi.process_joints(t[k], ys[k][:, None], np.repeat(u[k][None, :], 3, axis=0))
        for j, r in enumerate(alone):
            r.set_input(t[k], u[k])
            ref = r.process(t[k], ys[k, j:j + 1])
            assert isinstance(outs[j], Output) and isinstance(ref, Output), (k, j)
            np.testing.assert_array_equal(outs[j].estimate, ref.estimate)
            np.testing.assert_array_equal(outs[j].convergence, ref.convergence)
    assert all(o.observer.diagnostics()["mode"] == "tracking" for o in alone)
    assert [o.diagnostics()["mode"] for o in multi.observers] == ["tracking"] * 3


def test_the_window_sum_is_math_fsum():
    """The window's once-per-fill exact sum (kernel.exact_sum) is math.fsum, also on sums
    that cancel and span many magnitudes (the window's terms are >= 0; the algorithm is not
    restricted to them)."""
    rng = np.random.default_rng(4)
    cap = 301
    for trial in range(200):
        count = int(rng.integers(1, cap))
        terms = rng.standard_normal(count) * 10.0 ** rng.integers(-30, 30, count)
        if trial % 2:
            terms = np.abs(terms)
        wk = np.zeros(cap + TK.PARTIALS)
        head = int(rng.integers(0, cap))
        for q in range(count):
            wk[(head - count + q) % cap] = terms[q]
        assert TK.exact_sum(wk, 0, cap, head, count, cap) == math.fsum(terms), trial


def _asks_forever(op, st, nx, c, ic, wk, a, b, y, u, models):
    """A broken composition kernel: it asks for its acquirer's sample again and again."""
    rq = ic[ic[K.COMPOSED] + K.TAB_REQUEST]
    wk[rq + K.RQ_CHILD] = 1.0
    wk[rq + K.RQ_OP] = K.CALL_UPDATE
    return K.CALL


def test_a_composition_that_never_decides_is_stopped():
    """More than MAX_CALLS calls in one sample: the sample is rejected (observer_error) with
    the state as it was, instead of a loop without end."""
    obs = TrackObserver(_composition_cfg("ekf"), _stand_in_make(True))
    t, y, u = _stream(n=20)
    for k in range(10):
        obs.update_checked(t[k], y[k], u[k])
    before = obs._st.copy()
    kids = [J.kernel(_asks_forever, J.KERNEL)] + \
        [J.kernel(kid.KERNEL.kernel, J.KERNEL) for kid in (obs.acquirer, obs.tracker)]
    obs._kernels = J.function_list(kids, J.KERNELS)
    with pytest.raises(SampleRejected) as err:
        obs.update_checked(t[10], y[10], u[10])
    assert err.value.reason == "observer_error"
    np.testing.assert_array_equal(obs._st, before)
