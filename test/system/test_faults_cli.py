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

import domains
import processes
from faultkit import COUNTS
from fto_ros.bag import BagReader, BagWriter
from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate, uniform_grid
from fto_ros.replay import cli as replay_cli
from fto_ros.runner.plant_files import is_plant_file, params_files

ROOT = Path(__file__).resolve().parents[2]
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
               ROS_DOMAIN_ID=str(domains.take()), ROS_LOG_DIR=str(tmp_path / "roslog"))
    try:
        res = processes.run([sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args",
                             "--params-file", str(params)], cwd=ROOT, env=env,
                            capture_output=True, timeout=90)
    except subprocess.TimeoutExpired:
        # it started and ran: accepted (only files the replay refused come here, and the
        # node refuses them in ~2.5 s of CPU: the margin is for a loaded machine)
        return 0, ""
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


# -- output paths: nothing outside the output is ever touched (issue 19, item 1) ---------------
#: the attacks: --out aimed at something that is not an output fto_ros wrote, or at an input
ATTACKS = ("file", "symlink_to_file", "symlink_to_folder", "dangling_symlink", "fifo",
           "folder_with_content", "output_with_a_user_file", "output_holding_a_symlink",
           "output_of_another_kind", "input_bag", "inside_input_bag", "folder_holding_input",
           "empty")


def _arena(root: Path, bag: Path) -> dict[str, str]:
    """Build every attack's target under ``root`` (a temp dir); attack -> --out argument.
    A FIFO stands for a device node: no test ever aims at a real device."""
    root.mkdir()
    (root / "file.txt").write_text("precious\n")
    (root / "folder" / "sub").mkdir(parents=True)
    (root / "folder" / "notes.txt").write_text("mine\n")
    (root / "folder" / "sub" / "data.csv").write_text("1,2\n")
    os.symlink("file.txt", root / "link_to_file")
    os.symlink("folder", root / "link_to_folder")
    os.symlink("nowhere", root / "dangling")
    os.mkfifo(root / "fifo")
    shutil.copytree(bag, root / "holder" / "bag")
    with BagWriter(root / "user_file") as out:       # outputs fto_ros wrote, then altered
        out.clock(1)
    (root / "user_file" / "thesis.tex").write_text("mine\n")
    with BagWriter(root / "with_symlink") as out:
        out.clock(1)
    os.symlink("../file.txt", root / "with_symlink" / "metrics.json")
    report = root / "report_out"                    # an fto_ros output, but not a bag
    report.mkdir()
    (report / ".fto_ros_output").write_text('{"written_by": "fto_ros", "kind": "report"}\n')
    (report / "report.md").write_text("# report\n")
    with BagWriter(root / "clean_bag") as out:       # a bag output: another kind for fto-report
        out.clock(1)
    return {"file": "file.txt", "symlink_to_file": "link_to_file",
            "symlink_to_folder": "link_to_folder", "dangling_symlink": "dangling",
            "fifo": "fifo", "folder_with_content": "folder",
            "output_with_a_user_file": "user_file", "output_holding_a_symlink": "with_symlink",
            "output_of_another_kind": "report_out", "input_bag": "holder/bag",
            "inside_input_bag": "holder/bag/sub", "folder_holding_input": "holder", "empty": ""}


def _snapshot(root: Path) -> dict[str, tuple]:
    """Every path under ``root``: its type and content (files), target (symlinks)."""
    out = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            p = os.path.join(folder, name)
            st = os.lstat(p)
            if os.path.islink(p):
                out[p] = ("link", os.readlink(p))
            elif os.path.isfile(p):
                out[p] = ("file", Path(p).read_bytes())
            else:
                out[p] = ("other", st.st_mode)
    return out


def _command(prog: str, bag: Path, target: str, overwrite: bool) -> list[str]:
    over = ["--overwrite"] if overwrite else []
    if prog == "fto-replay":
        return [str(bag), "--params", str(EXPLICIT / "dc_motor_luenberger.yaml"), "--out", target,
                "--no-progress", *over]
    if prog == "fto-simulate":
        return ["dc_motor", "--duration", "0.01", "--out", target, *over]
    if prog == "fto-sweep":
        return ["--params", str(EXPLICIT / "dc_motor_luenberger.yaml"), "--bag", str(bag),
                "--out", target, "--workers", "1", "--quiet", *over]
    # fto-report replaces an earlier report of its own without being asked: no --overwrite
    return ["--bags-dir", str(bag.parent), "--config-dir", str(EXPLICIT), "--out", target,
            "--workers", "1", "--no-progress"]


def _main_of(prog: str):
    from fto_ros.cli import report, simulate
    from fto_ros.sweep import cli as sweep_cli
    return {"fto-replay": replay_cli.main, "fto-simulate": simulate.main,
            "fto-sweep": sweep_cli.main, "fto-report": report.main}[prog]


@pytest.mark.parametrize("prog", ["fto-replay", "fto-simulate", "fto-sweep", "fto-report"])
def test_output_path_attacks_touch_nothing(prog, short_bag, tmp_path, capsys, monkeypatch):
    """Every writing command, every attack, with --overwrite (fto-report: always): exit 2,
    one line on stderr, and not one byte, link or entry of the arena changed."""
    root = tmp_path / "arena"
    targets = _arena(root, short_bag)
    monkeypatch.chdir(root)                       # relative targets, as a user types them
    bag = root / "holder" / "bag"
    for attack in ATTACKS:
        if prog == "fto-simulate" and "input" in attack:
            continue                              # it reads no bag
        before = _snapshot(root)
        target = "clean_bag" if (prog, attack) == ("fto-report", "output_of_another_kind") \
            else targets[attack]
        rc = _main_of(prog)(_command(prog, bag, target, overwrite=True))
        err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        COUNTS[f"cli_out_{attack}"] += 1
        assert rc == 2, (prog, attack, rc, err)
        assert len(err) == 1 and err[0].startswith(f"{prog}: error: "), (prog, attack, err)
        assert "Traceback" not in err[0] and "unexpected" not in err[0], err
        assert _snapshot(root) == before, (prog, attack, "the arena changed")


@pytest.mark.parametrize("prog", ["fto-replay", "fto-sweep"])
def test_output_is_never_the_input_even_without_overwrite(prog, short_bag, tmp_path, capsys):
    root = tmp_path / "arena"
    targets = _arena(root, short_bag)
    bag = root / "holder" / "bag"
    for attack in ("input_bag", "inside_input_bag", "folder_holding_input"):
        before = _snapshot(root)
        rc = _main_of(prog)(_command(prog, bag, str(root / targets[attack]), overwrite=False))
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and "input" in err[0], (attack, rc, err)
        assert _snapshot(root) == before


def test_overwrite_replaces_an_output_fto_ros_wrote(short_bag, tmp_path, capsys):
    """The other side of the rule: --overwrite does replace what it may replace."""
    from fto_ros.cli import simulate
    sim = tmp_path / "sim"
    assert simulate.main(["dc_motor", "--duration", "0.01", "--out", str(sim)]) == 0
    assert (sim / ".fto_ros_output").is_file()
    assert simulate.main(["dc_motor", "--duration", "0.02", "--out", str(sim)]) == 1  # exists
    assert simulate.main(["dc_motor", "--duration", "0.02", "--out", str(sim), "--overwrite"]) == 0
    assert BagReader(sim).info().topics["/clock"].count == 21
    out = tmp_path / "o"
    args = [short_bag, "--params", EXPLICIT / "dc_motor_luenberger.yaml", "--out", out]
    assert replay_cli_run(capsys, *args)[0] == 0
    assert replay_cli_run(capsys, *args)[0] == 1                     # exists, no --overwrite
    rc, err, _ = replay_cli_run(capsys, *args, "--overwrite")
    assert rc == 0, err
    assert sorted(p.name for p in out.iterdir()) == [".fto_ros_output", "metadata.yaml",
                                                     "metrics.json", "o.mcap", "replay.png"]
