"""One test per failure the fault audit found (the robustness issue), each of which failed
before the fix: gaps, long pauses, silences, forward jumps of the log time, a health level
stuck at ERROR, absurd finite values, stamp storms, and bags that exit 0 with nothing in
them or lose messages silently.  (Parameter and expression refusals are in
test_settings.py and test_expressions.py; the random sequences in test_faults_*.py.)"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from faultkit import COUNTS, committed_configs, runner_for, stream_for
from fto_ros.bag import BagReader, BagWriter
from fto_ros.core import jit
from fto_ros.core.errors import ConfigError
from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate, uniform_grid
from fto_ros.observers import kernel as kernel_protocol
from fto_ros.observers.single_delay import continuous as single_delay_kernel
from fto_ros.replay import cli as replay_cli
from fto_ros.runner import ERROR, OK, Output, Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files
from fto_ros.runner.runner import HELD

ROOT = Path(__file__).resolve().parents[3]
SD = ROOT / "config" / "dc_motor_single_delay.yaml"
#: fto-replay's --params for it: the DC motor's plant file, then this tuning file
SD_ARGS = [a for p in params_files(SD) for a in ("--params", str(p))]
CONFIGS = {c.name: c for c in committed_configs()}


@pytest.fixture(scope="module")
def motor():
    t = uniform_grid(2.0, 1000.0)
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage,
                   output=dc_motor.output)
    return t, sim


def run(r: Runner, t, sim, keep=lambda k: True, offset=0.0):
    """Feed input + measurement k for every k kept; {k: Output or reason}."""
    out = {}
    for k in range(len(t)):
        if keep(k):
            r.set_input(t[k] + offset, sim.u_k[k])
            out[k] = r.process(t[k] + offset, sim.y[k])
    return out


# -- live and replay ----------------------------------------------------------------------------
@pytest.mark.parametrize("gap", [0.099, 0.101, 0.15, 0.3, 0.45])
def test_single_delay_bridges_any_gap_below_max_gap(motor, gap):
    """Was: a gap between tau and time.max_gap raised 'time outside the buffer' (observer_error)."""
    t, sim = motor
    r = Runner(load_params_files(params_files(SD)))
    g0 = 600
    g1 = g0 + int(round(gap * 1000))
    out = run(r, t, sim, keep=lambda k: not g0 < k < g1)
    assert not r.resets and not r.rejected, (r.resets, r.rejected)
    assert all(isinstance(o, Output) for o in out.values())
    # tau after the gap the estimate is exact again (up to the hold of y, as before it)
    late = [k for k in out if k >= g1 + 110]
    err = max(np.max(np.abs(out[k].estimate - sim.x[k])) for k in late)
    assert err < 3e-4, err


@pytest.mark.parametrize("name,pause", [("third_order_prescribed_time", 100.0),
                                        ("double_integrator_prescribed_time", 1e6)])
def test_prescribed_time_runs_on_after_a_long_pause(name, pause):
    """Was: after a long pause every later sample was rejected (step_too_long / too many
    windows) for good, and ~/reset did not help."""
    cfg = CONFIGS[name]
    r = runner_for(cfg)
    s = stream_for(cfg)
    ev = s.events
    half = next(i for i in range(len(ev) // 2, len(ev)) if ev[i][1] == "u")   # an input first
    for t, k, v in ev[:half]:
        r.set_input(t, v) if k == "u" else r.process(t, v)
    got = []
    for t, k, v in ev[half:]:
        if k == "u":
            r.set_input(t + pause, v)
        else:
            got.append(r.process(t + pause, v))
    assert got[0] == HELD                          # the pause is confirmed by the next sample
    assert all(isinstance(o, Output) for o in got[1:]), {o for o in got if isinstance(o, str)}
    assert r.resets == {"gap": 1} and not r.rejected
    r.reset()                                      # and a reset after it works too
    t_last = ev[-1][0] + pause
    r.set_input(t_last + 1e-3, ev[-2][2] if ev[-2][1] == "u" else [0.0])
    assert isinstance(r.process(t_last + 1e-3, ev[-1][2]), Output)


def test_sampled_single_delay_bounds_the_work_after_a_silence():
    """Was: an input after a silence integrated the whole gap in sub-steps without a cap
    (1 s: 0.73 s of CPU, 100 s: over 10 s, a stamp of 1e300: never)."""
    cfg = CONFIGS["dc_motor_single_delay_sampled"]
    s = stream_for(cfg)
    u = s.events[1][2] if s.events[1][1] == "u" else [1.0]
    for gap in (1.0, 100.0, 1e300):
        r = runner_for(cfg)
        obs = r.observer
        for t, k, v in s.events[:400]:
            r.set_input(t, v) if k == "u" else r.process(t, v)
        t_last = s.events[399][0]
        s_before = obs._s
        res = r.set_input(t_last + gap, u)
        assert res in (None, "input_bad_stamp")
        assert (res == "input_bad_stamp") == (gap > 2 ** 31)
        assert obs._s == s_before                  # beyond what the predictor bridges
        if gap > 2 ** 31:
            continue
        # the observer's own bound, without the runner's: a longer interval is not
        # integrated, the longest it bridges takes at most MAX_SUBSTEPS sub-steps
        obs.advance(t_last + gap, u)
        assert obs._s == s_before
        obs.advance(t_last + 0.9 * obs.max_step, u)
        assert obs._s > s_before
        assert 0 < obs.last_substeps <= 1000, obs.last_substeps


def test_sampled_single_delay_input_hold_foh_is_used():
    """Was: input_hold: foh was silently ignored in the sampled form."""
    cfg = CONFIGS["dc_motor_single_delay_sampled"]
    s = stream_for(cfg)
    outs = {}
    for hold in ("zoh", "foh"):
        r = runner_for(cfg, **{"single_delay.input_hold": hold})
        res = []
        for t, k, v in s.events[:1500]:
            if k == "u":
                r.set_input(t, v)
            else:
                res.append(r.process(t, v))
        outs[hold] = np.array([o.estimate for o in res if isinstance(o, Output)])
    assert outs["zoh"].shape == outs["foh"].shape
    assert np.max(np.abs(outs["zoh"] - outs["foh"])) > 1e-9


def _write_motor_bag(path, t, sim, shift_after=None, shift=0.0, stamp_offset=0.0):
    with BagWriter(path) as bag:
        for k in range(len(t)):
            tk = t[k] + stamp_offset + (shift if shift_after is not None and k >= shift_after else 0.0)
            ns = int(round(tk * 1e9))
            bag.float_array("/dc_motor/input", ns, sim.u_k[k])
            bag.float_array("/dc_motor/measured_output", ns, sim.y[k])
            bag.float_array("/dc_motor/true_state", ns, sim.x[k])
    return path


def test_replay_across_a_forward_jump_of_the_log_time(motor, tmp_path, capsys):
    """Was: one /diagnostics per bag-second across a forward jump: 1e6 s never finished."""
    t, sim = motor
    bag = _write_motor_bag(tmp_path / "jump", t, sim, shift_after=1000, shift=1e6)
    rc = replay_cli.main([str(bag), *SD_ARGS, "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["restarts_by_reason"] == {"gap": 1}
    assert m["output_topics"]["/diagnostics"] <= 6      # ~2 s of bag, not 1e6 statuses


_SINGLE_DELAY = jit.kernel(single_delay_kernel.kernel, jit.KERNEL)


def _failing_kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The single_delay kernel with a bug: the STEP its countdown (the last float of the work
    memory) reaches zero at commits a NaN estimate."""
    code = _SINGLE_DELAY(op, st, nx, c, ic, wk, a, b, y, u, models)
    if op == jit.STEP:
        wk[wk.shape[0] - 1] -= 1.0
        if wk[wk.shape[0] - 1] == 0.0:
            nx[ic[kernel_protocol.EST] + 1] = math.nan
    return code


def test_diagnostics_error_clears_after_clean_data_and_after_reset(motor):
    """Was: one observer failure (an observer_error restart then, a non-finite estimate from
    a compiled kernel now) kept /diagnostics at ERROR for good."""
    t, sim = motor
    r = Runner(dict(load_params_files(params_files(SD)), **{"diagnostics.window": 0.5}))
    obs = r.observer
    obs._wk = np.append(obs._wk, 301.0)             # the bug's countdown, in the work memory
    obs._kernels = jit.function_list([jit.kernel(_failing_kernel, jit.KERNEL)], jit.KERNELS)
    r._stack()                                        # the runner's rows: the longer work memory
    levels = []
    for k in range(len(t)):
        r.set_input(t[k], sim.u_k[k])
        r.process(t[k], sim.y[k])
        if k % 100 == 99:
            levels.append(r.status(t[k]).level)
    assert r.resets["non_finite_state"] == 1
    assert ERROR in levels[2:5]                        # the failure at 0.3 s shows ...
    assert levels[-1] == OK and levels[-5:] == [OK] * 5  # ... and clears 0.5 s later
    # a ~/reset clears it at once
    obs._wk[-1] = 1.0
    r.set_input(t[-1] + 1e-3, sim.u_k[-1])
    assert r.process(t[-1] + 1e-3, 2 * sim.y[-1] - sim.y[-2]) == "non_finite_estimate"
    assert r.status(t[-1] + 2e-3).level == ERROR
    r.reset()
    assert r.status(t[-1] + 3e-3).level != ERROR


def test_absurd_finite_values_never_reach_the_observer(motor):
    """Was: y or u = 1e300 for 100 ms left the estimate 1e287 off, nothing counted."""
    t, sim = motor
    ref = run(Runner(load_params_files(params_files(SD))), t, sim)
    r = Runner(load_params_files(params_files(SD)))
    out = {}
    for k in range(len(t)):
        if 500 <= k < 600:                             # 100 ms of absurd values on both
            assert r.set_input(t[k], [1e300]) == "input_implausible"
            assert r.process(t[k] + 5e-4, [-1e300]) == "measurement_implausible"
        r.set_input(t[k], sim.u_k[k])
        out[k] = r.process(t[k], sim.y[k])
    assert r.rejected == {"input_implausible": 100, "measurement_implausible": 100}
    for k in range(len(t)):
        np.testing.assert_array_equal(out[k].estimate, ref[k].estimate)


@pytest.mark.parametrize("junk", [-1.0, "negative"])
def test_junk_stamps_never_start_a_restart_storm(motor, junk):
    """Was: a JointState stamped 1 s back or at a negative time gave a time_jump restart then
    a gap restart, message after message (2,101 restarts in 60 s)."""
    t, sim = motor
    r = Runner(load_params_files(params_files(SD)))
    for k in range(len(t)):
        r.set_input(t[k], sim.u_k[k])
        out = r.process(t[k], sim.y[k])
        assert isinstance(out, Output)
        stamp = t[k] + junk if junk != "negative" else -t[k] - 1.0
        r.process(stamp, sim.y[k])                     # one junk stamp after every sample
    assert not r.resets
    assert sum(r.rejected.values()) >= len(t) - 1       # (the last one may still be held)


# -- bags ---------------------------------------------------------------------------------------
def _cli(capsys, *args):
    rc = replay_cli.main([str(a) for a in args] + ["--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    return rc, err


@pytest.mark.parametrize("what", ["all_nan", "wrong_length", "no_input_messages", "beyond_int32"])
def test_a_bag_without_usable_samples_fails(motor, tmp_path, capsys, what):
    """Was: exit 0 with 0-1 samples accepted."""
    t, sim = motor
    path = tmp_path / what
    with BagWriter(path) as bag:
        for k in range(200):
            ns = int(round(t[k] * 1e9)) + (2 ** 31 * 10 ** 9 if what == "beyond_int32" else 0)
            if what != "no_input_messages":
                bag.float_array("/dc_motor/input", ns, sim.u_k[k])
            else:
                bag.float_array("/dc_motor/input", ns + 10 ** 12, sim.u_k[k])   # after the end
            y = {"all_nan": [math.nan], "wrong_length": [1.0, 2.0]}.get(what, sim.y[k])
            bag.float_array("/dc_motor/measured_output", ns, y)
    rc, err = _cli(capsys, path, *SD_ARGS, "--out", tmp_path / "o")
    assert rc == 1 and len(err) == 1 and "no sample accepted" in err[0], err


def _flip_bytes(src: Path, dst: Path, where: float, n: int = 1) -> None:
    import shutil
    shutil.copytree(src, dst)
    mcap = next(dst.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    i = int(len(data) * where)
    for j in range(n):
        data[i + j] ^= 0xFF
    mcap.write_bytes(bytes(data))


@pytest.mark.parametrize("where", [0.2, 0.5, 0.8])
def test_a_damaged_bag_never_loses_messages_silently(tmp_path, capsys, where):
    """Was: one flipped byte made the reader fall back to rosbags, which dropped 245
    messages, and the replay still exited 0."""
    bag = tmp_path / "flipped"
    _flip_bytes(ROOT / "bags" / "dc_motor_nominal", bag, where)
    rc, err = _cli(capsys, bag, *SD_ARGS, "--out", tmp_path / "o")
    if rc == 0:
        # the byte hit something that does not matter (e.g. a value): everything was read
        m = json.loads((tmp_path / "o" / "metrics.json").read_text())
        with BagReader(ROOT / "bags" / "dc_motor_nominal") as b:
            assert m["sample_count"] == b.topics["/dc_motor/measured_output"].count
    else:
        assert rc == 1 and len(err) == 1 and "flipped" in err[0], err


def test_an_undecodable_message_is_one_line_naming_the_topic(motor, tmp_path, capsys):
    """Was: decode errors surfaced as 'unexpected SerdeError' lines."""
    t, sim = motor
    path = tmp_path / "garbage"
    with BagWriter(path) as bag:
        raw = bag.raw_writer("/dc_motor/measured_output", "std_msgs/msg/Float64MultiArray")
        for k in range(100):
            ns = int(round(t[k] * 1e9))
            bag.float_array("/dc_motor/input", ns, sim.u_k[k])
            raw(ns, b"\x00\x01\x00\x00" + b"\xff" * (3 + k % 5))
    rc, err = _cli(capsys, path, *SD_ARGS, "--out", tmp_path / "o")
    assert rc == 1 and len(err) == 1, err
    assert "/dc_motor/measured_output" in err[0] and "decode" in err[0] and "unexpected" not in err[0]


# -- parameters the design cannot use -------------------------------------------------------------
@pytest.mark.parametrize("value", ["1.0e-300", "1.0e+300", "9223372036854775808", "1e6"])
def test_a_design_that_fails_is_one_line_exit_2_without_warnings(motor, tmp_path, value):
    """Was: scipy and numpy warnings on stderr, then 'unexpected LinAlgError', exit 1 (the
    live node died of the same LinAlgError out of Runner.reconfigure).  A real process, so
    that whatever Python would print reaches stderr."""
    t, sim = motor
    bag = tmp_path / "bag"
    _write_motor_bag(bag, t[:300], sim)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, "-c", "import sys; from fto_ros.replay.cli import main; "
                          "sys.exit(main())", str(bag), *SD_ARGS, "--set",
                          f"single_delay.tau={value}", "--out", str(tmp_path / "o"), "--no-progress"],
                         capture_output=True, text=True, env=env, timeout=120)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith("fto-replay: error: parameter 'single_delay."), lines[0]
    assert "Warning" not in res.stderr and not res.stdout.strip()


# -- sizes ----------------------------------------------------------------------------------------
def _no_parsing(monkeypatch):
    """Make any expression parse fail the test: a refusal must come before any work."""
    def parse(*args, **kwargs):
        raise AssertionError("an expression was parsed before the size check")
    import fto_ros.core.named_model as named_model
    import fto_ros.core.symbolic_model as symbolic_model
    monkeypatch.setattr(named_model, "parse", parse)
    monkeypatch.setattr(symbolic_model, "parse", parse)


BIG = 100_000


@pytest.mark.parametrize("what", ["constants", "states", "inputs", "outputs", "array",
                                  "some_constants", "some_states"])
def test_a_huge_plant_block_is_refused_before_any_work(monkeypatch, what):
    """Was: a plant block with 100,000 constants was not refused within 40 s."""
    flat = load_params_files(params_files(ROOT / "config" / "dc_motor_ekf.yaml"))
    change, name = {
        "constants": ({"plant.constants": [f"c{i}={i}" for i in range(BIG)]}, "plant.constants"),
        "some_constants": ({"plant.constants": [f"c{i}={i}" for i in range(5000)]}, "plant.constants"),
        "states": ({"plant.states": [f"x{i}" for i in range(BIG)], "plant.f": ["0"] * BIG},
                   "plant.states"),
        "some_states": ({"plant.states": [f"x{i}" for i in range(500)], "plant.f": ["0"] * 500},
                        "plant.states"),
        "inputs": ({"plant.inputs": [f"u{i}" for i in range(100)]}, "plant.inputs"),
        "outputs": ({"plant.h": ["q"] * 100}, "plant.h"),
        "array": ({"limits.measurement": [1.0] * 10 ** 6}, "limits.measurement"),
    }[what]
    _no_parsing(monkeypatch)
    with pytest.raises(ConfigError) as err:
        Runner({**flat, **change})
    assert err.value.parameter == name and "at most" in str(err.value), err.value


def test_a_huge_params_file_is_one_line_exit_2(tmp_path, capsys):
    plant = tmp_path / "plant.yaml"
    plant.write_text("/**:\n  ros__parameters:\n    plant:\n      constants: ["
                     + ", ".join(f"'c{i}={i}'" for i in range(BIG)) + "]\n")
    rc, err = _cli(capsys, ROOT / "bags" / "dc_motor_nominal", *SD_ARGS, "--params", plant,
                   "--out", tmp_path / "o")
    assert rc == 2 and len(err) == 1 and "plant.constants" in err[0] and "at most" in err[0], err


# -- issue 19: the JointState intake the node and the replay share (runner/messages.py) --------
class _Stamp:
    def __init__(self, ns: int):
        self.sec, self.nanosec = ns // 10**9, ns % 10**9


class _Header:
    def __init__(self, ns: int):
        self.stamp = _Stamp(ns)


class _JS:
    """A JointState as either message class looks to the intake (duck-typed)."""

    def __init__(self, ns, name, position=(), velocity=(), effort=()):
        self.header = _Header(ns)
        self.name, self.position, self.velocity, self.effort = name, position, velocity, effort


JS_SETTINGS = {"joint_states.output_joints": ["joint1"], "joint_states.output_field": "position",
               "joint_states.input_joints": ["joint1"], "joint_states.input_field": "effort",
               "time.max_gap": 0.5, "time.future_tolerance": 0.5}
WALL = 1.7e9          # a wall clock (s since 1970)


@pytest.mark.parametrize("names, position, effort, reason", [
    (["joint1", "joint1"], [0.5, 9.0], [2.0, 2.0], "joint_states_duplicate_name"),
    (["joint2", "joint1", "joint2"], [0.1, 0.5, 0.1], [0.0, 2.0, 0.0], "joint_states_duplicate_name"),
    (["joint1"], [0.5, 9.0], [2.0], "joint_states_position_missing"),     # longer than name
    (["joint1"], [0.5], [], "joint_states_effort_missing"),               # the input field
    (["joint2"], [0.5], [2.0], "joint_states_joint_missing"),
])
def test_joint_state_intake_rejects_ambiguous_and_inconsistent_messages(names, position, effort,
                                                                         reason):
    """Was: a joint named twice was taken with its first value.  Which value is meant cannot be
    known: the message is rejected, counted, as one of inconsistent lengths (a used field)."""
    from fto_ros.runner.messages import joint_state_sample
    msg = _JS(int(WALL * 1e9), names, position, effort=effort)
    assert joint_state_sample(msg, JS_SETTINGS, WALL) == reason
    COUNTS["js_intake"] += 1


def test_joint_state_intake_ignores_an_unused_field_of_another_length():
    from fto_ros.runner.messages import joint_state_sample
    msg = _JS(int(WALL * 1e9), ["joint1"], [0.5], velocity=[1.0, 2.0, 3.0], effort=[2.0])
    assert joint_state_sample(msg, JS_SETTINGS, WALL) == (WALL, [0.5], [2.0])


@pytest.mark.parametrize("clock, verdict", [
    (None, "taken"),          # the node on sim time (before /clock, or /clock may lag)
    (0.0, "taken"),           # a bag or simulation that starts at 0 (replay: log time 0)
    (0.4, "taken"),           # ... within time.max_gap of its start
    (WALL, "zero_stamp"),     # the node on wall time; the replay of a wall-clock recording
])
def test_zero_stamp_one_rule_for_node_and_replay(clock, verdict):
    """Was: the node rejected a first sample stamped 0 (without sim time), the replay took it:
    now one rule in the intake both call, against the clock each has (the node's wall clock,
    the replay's log time)."""
    from fto_ros.runner.messages import joint_state_sample
    got = joint_state_sample(_JS(0, ["joint1"], [0.5], effort=[2.0]), JS_SETTINGS, clock)
    assert (got if isinstance(got, str) else "taken") == verdict


def _js_params(tmp_path) -> Path:
    import yaml
    doc = yaml.safe_load((ROOT / "test" / "data" / "dc_motor_explicit" /
                          "dc_motor_luenberger.yaml").read_text())
    p = doc["observer_node"]["ros__parameters"]
    p["source"] = "joint_states"
    p["joint_states"].update(input_joints=["joint1"], input_field="effort")
    path = tmp_path / "js.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("base_ns, rejected", [(0, 0), (int(WALL * 1e9), 1)])
def test_replay_applies_the_zero_stamp_rule_of_the_node(motor, tmp_path, base_ns, rejected):
    """A JointState bag whose first stamp is 0: replayed from log time 0 (a simulation) it is
    taken; in a wall-clock recording (log times ~1.7e9 s) it is an unstamped message, rejected
    as 'zero_stamp', as the node without sim time rejects it."""
    from fto_ros.replay import replay
    t, sim = motor
    bag = tmp_path / "js"
    with BagWriter(bag) as w:
        for k in range(300):
            log_ns = base_ns + int(round(t[k] * 1e9))
            stamp_ns = 0 if k == 0 else log_ns
            w.joint_state("/dc_motor/joint_states", log_ns, stamp_ns, ["joint1"],
                          position=sim.y[k], effort=sim.u_k[k])
            w.float_array("/dc_motor/true_state", log_ns, sim.x[k])
    m = replay(bag, _js_params(tmp_path), tmp_path / "out", progress=False, plot=False)
    assert m["rejected_by_reason"].get("zero_stamp", 0) == rejected, m["rejected_by_reason"]
    assert m["samples_accepted"] == 300 - rejected


def test_replay_rejects_a_joint_named_twice(motor, tmp_path):
    from fto_ros.replay import replay
    t, sim = motor
    bag = tmp_path / "dup"
    with BagWriter(bag) as w:
        for k in range(300):
            ns = int(round(t[k] * 1e9))
            if k % 50 == 25:      # a second robot's joint1 in the same message
                w.joint_state("/dc_motor/joint_states", ns, ns, ["joint1", "joint1"],
                              position=[float(sim.y[k][0]), 100.0], effort=[sim.u_k[k][0]] * 2)
            else:
                w.joint_state("/dc_motor/joint_states", ns, ns, ["joint1"], position=sim.y[k],
                              effort=sim.u_k[k])
            w.float_array("/dc_motor/true_state", ns, sim.x[k])
    m = replay(bag, _js_params(tmp_path), tmp_path / "out", progress=False, plot=False)
    assert m["rejected_by_reason"] == {"joint_states_duplicate_name": 6}, m["rejected_by_reason"]
    assert m["samples_accepted"] == 294
