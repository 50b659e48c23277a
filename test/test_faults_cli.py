"""Fault injection through the command line: mutated params files and damaged bags through
``fto-replay`` (its ``main``, in process: the same code the console script runs), and a
sample of the mutated params files through the live node, which must accept and refuse
exactly what the replay does, with the same message.

What must hold: the exit code follows the contract (0 done, 2 bad parameters or
arguments, 1 bad bag or runtime failure), stderr is one line and never a traceback or an
"unexpected" error, every run returns within a (generous) bound, and no text from a
params file is ever executed.  Seeded: the same seeds give the same mutations."""
from __future__ import annotations

import copy
import json
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from faultkit import COUNTS
from fto_ros.bag import BagReader, BagWriter
from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate, uniform_grid
from fto_ros.replay import cli as replay_cli
from fto_ros.runner.plant_files import is_plant_file, params_files

ROOT = Path(__file__).resolve().parents[1]
EXPLICIT = ROOT / "test" / "data" / "dc_motor_explicit"
#: tuning files (run with their plant file, which a mutation may hit too) and explicit files
CONFIGS = [c for c in sorted((ROOT / "config").glob("dc_motor_*.yaml")) if not is_plant_file(c)] + [
    ROOT / "config" / "third_order_prescribed_time.yaml", EXPLICIT / "dc_motor_hosm.yaml"]
HANG_S = 60.0                 # a hang detector, not a speed test
N_PARAMS, N_BAGS = 60, 40     # mutations tried (seeded)


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory):
    """0.6 s of the DC motor at 1 kHz on the /dc_motor topics (fast replays)."""
    t = uniform_grid(0.6, 1000.0)
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage,
                   output=dc_motor.output)
    path = tmp_path_factory.mktemp("bags") / "short"
    with BagWriter(path) as bag:
        for k in range(len(t)):
            ns = int(round(t[k] * 1e9)) + 10 ** 9
            bag.clock(ns)
            bag.float_array("/dc_motor/input", ns, sim.u_k[k])
            bag.float_array("/dc_motor/measured_output", ns, sim.y[k])
            bag.joint_state("/dc_motor/joint_states", ns, ns, ["joint1"], position=sim.y[k])
            bag.float_array("/dc_motor/true_state", ns, sim.x[k])
    return path


def replay_cli_run(capsys, *args) -> tuple[int, list[str], float]:
    t0 = time.perf_counter()
    rc = replay_cli.main([str(a) for a in args] + ["--no-progress"])
    dt = time.perf_counter() - t0
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return rc, err, dt


def check_contract(rc: int, err: list[str], dt: float, allowed=(0, 1, 2)) -> None:
    assert rc in allowed, (rc, err)
    assert dt < HANG_S
    text = "\n".join(err)
    assert "Traceback" not in text and "unexpected" not in text, text
    if rc == 0:
        assert not err, err
    else:
        assert len(err) == 1 and err[0].startswith("fto-replay: error: "), err
        assert len(err[0]) < 1200, len(err[0])
        if rc == 2:
            assert "parameter '" in err[0] or "usage" in err[0], err[0]


# -- params files ---------------------------------------------------------------------------------
def _leaves(tree, path=()):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _leaves(v, path + (k,))
    else:
        yield path, tree


def _set(tree, path, value):
    for k in path[:-1]:
        tree = tree[k]
    if value is _DELETE:
        del tree[path[-1]]
    else:
        tree[path[-1]] = value


_DELETE = object()


def mutate_params(doc: dict, rng: np.random.Generator, canary: Path) -> tuple[str, str | dict]:
    """(family, mutated document or raw text) of one seeded mutation."""
    doc = copy.deepcopy(doc)
    block = next(iter(doc))                    # observer_node, or /** in a plant file
    params = doc[block]["ros__parameters"]
    leaves = list(_leaves(params))
    path, value = leaves[rng.integers(len(leaves))]
    kind = rng.integers(14)
    if kind == 0:
        _set(params, path, _DELETE)
        return "delete_key", doc
    if kind == 1:
        _set(params, path, None)
        return "null", doc
    if kind == 2:
        _set(params, path, int(10 ** 400) if rng.random() < 0.5 else -(10 ** 309))
        return "huge_int", doc
    if kind == 3:
        _set(params, path, rng.choice(["abc", "", "1.0.0", "None"]).item())
        return "string", doc
    if kind == 4:
        _set(params, path, [[1.0, 2.0], [3.0]])
        return "nested_list", doc
    if kind == 5:
        _set(params, path, {"a": 1})
        return "mapping", doc
    if kind == 6:
        _set(params, path, float(rng.choice([np.nan, np.inf, -np.inf, -1.0, 0.0, 1e308])))
        return "number", doc
    if kind == 7:
        exprs = [(p, v) for p, v in leaves if isinstance(v, list) and v and isinstance(v[0], str)
                 and p[-1] in ("F", "F1", "F2", "f", "h")]
        if exprs:
            p, v = exprs[rng.integers(len(exprs))]
            junk = rng.choice(["9**9**9**9", "10**10**10", f"__import__('os').system('touch {canary}')",
                               "y0 + " * 30000 + "1", "1/0", "Rational(1, 0)", "exp(1000)",
                               "(" * 300 + "y0" + ")" * 300, "y0.__class__", "lambda: 1"]).item()
            v = list(v)
            v[rng.integers(len(v))] = junk
            _set(params, p, v)
            return "expression", doc
        _set(params, path, True)
        return "bool", doc
    if kind == 8:
        _set(params, path, [1, 2.0])
        return "mixed_list", doc
    if kind == 9:
        doc = {"another_node": doc[block]}
        return "block_name", doc
    if kind == 10:
        text = yaml.safe_dump(doc)
        return "truncated_yaml", text[:int(rng.integers(1, len(text)))]
    if kind == 11:
        bomb = ("a: &a [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]\n"
                + "".join(f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n"
                          for p, c in zip("abcdefgh", "bcdefghi")))
        return "alias_bomb", bomb + yaml.safe_dump(doc)
    if kind == 12:
        params[f"typo_{rng.integers(100)}"] = 1.0
        return "unknown_name", doc
    _set(params, path, "[" * 5000 + "]" * 5000)
    return "deep_text", doc


@pytest.mark.slow
def test_mutated_params_files_through_fto_replay(short_bag, tmp_path, capsys):
    canary = tmp_path / "executed"
    rng = np.random.default_rng(20261201)
    for i in range(N_PARAMS):
        files = params_files(CONFIGS[i % len(CONFIGS)])
        victim = int(rng.integers(len(files)))          # the tuning file, or its plant file
        family, mutated = mutate_params(yaml.safe_load(files[victim].read_text()), rng, canary)
        path = tmp_path / f"m{i}.yaml"
        path.write_text(mutated if isinstance(mutated, str) else yaml.safe_dump(mutated))
        files[victim] = path
        args = [a for f in files for a in ("--params", f)]
        rc, err, dt = replay_cli_run(capsys, short_bag, *args, "--out", tmp_path / f"o{i}")
        COUNTS[f"cli_params_{family}"] += 1
        check_contract(rc, err, dt)
        assert not canary.exists(), f"text from a params file was executed ({family})"


#: run-time parameter extremes as ROS spells them (test_faults_param_extremes.py runs them all
#: through the runner; a seeded subset here through the command line)
EXTREMES = ("0", "-0.0", "1.0e-300", "1e-300", "1.0e+300", "1e300", "9223372036854775808",
            "-9223372036854775809", "5e-324", "1e400", ".nan", ".inf", "-.inf", "1e6")
N_EXTREMES = 30


def _number_params(files) -> list[str]:
    """The observer's own int and double parameters of a tuning file's observer."""
    from fto_ros.observers import observer_class
    from fto_ros.runner.params_file import load_params_files
    cls = observer_class(load_params_files(files)["observer.type"])
    return [f"{cls.TYPE}.{p.name}" for p in cls.PARAMS if p.kind in ("int", "double")]


@pytest.mark.slow
def test_parameter_extremes_through_fto_replay(short_bag, tmp_path, capsys):
    """--set NAME=VALUE and the same value in a params file: exit 0 or 2, one line, and no
    warning (scipy's, numpy's) printed."""
    rng = np.random.default_rng(2262)
    motor = [c for c in CONFIGS if c.stem.startswith("dc_motor")]     # the short bag's topics
    for i in range(N_EXTREMES):
        files = params_files(motor[i % len(motor)])
        names = _number_params(files)
        name, text = names[int(rng.integers(len(names)))], str(rng.choice(EXTREMES))
        if i % 2:
            args = [a for f in files for a in ("--params", f)] + ["--set", f"{name}={text}"]
            family = "set"
        else:
            section, key = name.split(".")
            path = tmp_path / f"x{i}.yaml"
            path.write_text(f"observer_node:\n  ros__parameters:\n    {section}:\n      {key}: {text}\n")
            args = [a for f in files + [path] for a in ("--params", f)]
            family = "file"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rc, err, dt = replay_cli_run(capsys, short_bag, *args, "--out", tmp_path / f"o{i}")
        COUNTS[f"cli_extreme_{family}"] += 1
        check_contract(rc, err, dt, allowed=(0, 2))
        assert not caught, (name, text, [str(w.message) for w in caught])


# -- bags -----------------------------------------------------------------------------------------
def damage_bag(src: Path, dst: Path, rng: np.random.Generator) -> str:
    """Copy the bag src to dst and damage it one seeded way; the family."""
    shutil.copytree(src, dst)
    mcap = next(dst.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    kind = rng.integers(7)
    if kind == 0:
        mcap.write_bytes(bytes(data[:int(rng.integers(0, len(data)))]))
        return "truncated"
    if kind == 1:
        for i in rng.integers(0, len(data), size=int(rng.integers(1, 9))):
            data[i] ^= int(rng.integers(1, 256))
        mcap.write_bytes(bytes(data))
        return "bit_flips"
    if kind == 2:
        mcap.write_bytes(b"")
        return "empty_file"
    if kind == 3:
        (dst / "metadata.yaml").unlink()
        return "no_metadata"
    if kind == 4:
        (dst / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
        return "bad_metadata"
    if kind == 5:
        meta = (dst / "metadata.yaml").read_text().replace("/dc_motor/measured_output", "/other")
        (dst / "metadata.yaml").write_text(meta)
        return "metadata_mismatch"
    shutil.rmtree(dst)
    with BagReader(src) as b:
        msgs = list(b.messages(["/dc_motor/measured_output", "/dc_motor/input"]))
    with BagWriter(dst) as out:           # stamps backward and a wrong type on the input topic
        for topic, t_ns, msg in reversed(msgs):
            if topic.endswith("input") and rng.random() < 0.5:
                out.joint_state(topic.replace("input", "input_js"), t_ns, t_ns, ["j"], position=[0.0])
            out.float_array(topic, t_ns, msg.data)
    return "reordered"


@pytest.mark.slow
def test_damaged_bags_through_fto_replay(short_bag, tmp_path, capsys):
    rng = np.random.default_rng(42)
    params = EXPLICIT / "dc_motor_luenberger.yaml"
    with BagReader(short_bag) as b:
        listed = b.topics["/dc_motor/measured_output"].count
    for i in range(N_BAGS):
        bag = tmp_path / f"b{i}"
        family = damage_bag(short_bag, bag, rng)
        rc, err, dt = replay_cli_run(capsys, bag, "--params", params, "--out", tmp_path / f"o{i}")
        COUNTS[f"cli_bag_{family}"] += 1
        check_contract(rc, err, dt, allowed=(0, 1))
        if rc == 0:   # the damage missed what is read: then everything the bag lists was read
            m = json.loads((tmp_path / f"o{i}" / "metrics.json").read_text())
            assert m["sample_count"] == listed or family == "reordered", (family, m["sample_count"])


# -- the node refuses and accepts the same files, with the same message ----------------------------
def _node_run(params: Path, tmp_path: Path) -> tuple[int, str]:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(20 + os.getpid() % 60), ROS_LOG_DIR=str(tmp_path / "roslog"))
    try:
        res = subprocess.run([sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args",
                              "--params-file", str(params)], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=20)
    except subprocess.TimeoutExpired:
        return 0, ""          # it started and ran: accepted
    return res.returncode, (res.stdout + res.stderr).strip()


@pytest.mark.slow
def test_node_and_replay_refuse_the_same_files_alike(short_bag, tmp_path, capsys):
    rng = np.random.default_rng(7)
    doc = yaml.safe_load((EXPLICIT / "dc_motor_luenberger.yaml").read_text())
    seen = 0
    for i in range(40):
        family, mutated = mutate_params(doc, rng, tmp_path / "canary")
        path = tmp_path / f"n{i}.yaml"
        path.write_text(mutated if isinstance(mutated, str) else yaml.safe_dump(mutated))
        rc, err, _ = replay_cli_run(capsys, short_bag, "--params", path, "--out", tmp_path / f"o{i}")
        if rc != 2:
            continue                        # the node's acceptance is tested live elsewhere
        node_rc, out = _node_run(path, tmp_path)
        COUNTS[f"cli_node_{family}"] += 1
        assert node_rc == 2, (family, out)
        lines = [line for line in out.splitlines() if line.strip()]
        assert len(lines) == 1 and "Traceback" not in out, out
        problem = err[0].split("fto-replay: error: ", 1)[1]
        assert problem in lines[0], (problem, lines[0])
        seen += 1
        if seen == 6:
            break
    assert seen >= 4
