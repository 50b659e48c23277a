"""``fto-identify`` end to end: simulated bags of the test arm (fto-simulate --urdf with model
error, unknown friction, jitter, lost messages, a push, a payload), the params file it
writes and what the node's params reading makes of it; every refusal one line with its exit
code; it writes nothing but --out."""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import identify_data as D
from fto_ros.arm.identify_params import MARKER, prior_model, read
from fto_ros.bag import BagWriter
from fto_ros.cli.arm_bag import read_arm_bag
from fto_ros.cli.identify import main
from fto_ros.cli.simulate import main as simulate
from fto_ros.runner.params_file import load_params_files

MOTION = ["--q0", "0.2,0.4,-0.3", "--amplitude", "0.6,0.5,0.7", "--period", "2.1,1.7,1.3"]
PUSH = ["--contact", "l3,1.5,0.1,30,0,0"]


def _plant(folder: Path, urdf: Path, name: str = "plant", joints: bool = True,
           **extra) -> Path:
    lines = ["/**:", "  ros__parameters:", f"    plant.urdf: {urdf}"] + \
        (["    joints: [j1, j2, j3]"] if joints else []) + \
        [f"    {k.replace('__', '.')}: {v}" for k, v in extra.items()]
    path = folder / f"{name}.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    d = tmp_path_factory.mktemp("identify")
    urdf = d / "arm.urdf"
    urdf.write_text(D.urdf_with_armature())
    common = ["--urdf", str(urdf), "--duration", "3", "--model-error", "0.05",
              "--model-seed", "4", "--friction", "0.5,1,0.5,1", *MOTION]
    runs = {"arm": ["--jitter", "50", "--loss", "0.005", *PUSH],
            "busy": sum((["--contact", f"l3,{0.4 + 0.7 * k},0.15,30,0,0"] for k in range(4)), []),
            "grasp": ["--duration", "2", "--payload", "l3,0.7,0.02,-0.03,0.08"]}
    for name, args in runs.items():
        assert simulate([*common, "--out", str(d / name), "--seed", "5", *args]) == 0
    names = ["j1", "j2", "j3"]
    with BagWriter(d / "no_effort") as bag:
        for k in range(300):
            bag.joint_state("/arm/joint_states", k * 1_000_000, k * 1_000_000, names,
                            position=[0.1 * k * 1e-3] * 3)
    with BagWriter(d / "two_joints") as bag:
        for k in range(300):
            bag.joint_state("/arm/joint_states", k * 1_000_000, k * 1_000_000, names[:2],
                            position=[0.0, 0.0], effort=[1.0, 1.0])
    return d, _plant(d, urdf)


def identify(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as done:
        code = done.code
    out, err = capsys.readouterr()
    return code, out, err


def test_identify_writes_a_params_file_the_node_merges(arm, capsys):
    d, plant = arm
    out = d / "identified.yaml"
    before = sorted(p.name for p in d.iterdir() if p.name != "identified.yaml")
    code, text, err = identify(capsys, d / "arm", "--params", plant, "--out", out)
    assert code == 0, err
    assert sorted(p.name for p in d.iterdir()) == sorted(before + ["identified.yaml"])
    assert re.search(r"windows left out as contacts: \d+ \(1\.5\d-1\.[67]\d s\)", text)
    assert "condition number" in text and "encoder noise" in text
    written = out.read_text()
    assert written.splitlines()[0] == MARKER and "# residual RMS per joint" in written
    assert "+-" in written and "/**:" in written
    s = read(load_params_files([plant, out]))
    model = prior_model(s)
    _, meta = read_arm_bag(d / "arm")
    np.testing.assert_allclose(model.viscous, meta["friction"]["viscous"], rtol=0.05)
    np.testing.assert_allclose(model.coulomb, meta["friction"]["coulomb"], rtol=0.05)
    assert s["plant.inertia_delta.links"] and len(s["plant.inertia_delta.values"]) == \
        10 * len(s["plant.inertia_delta.links"])
    rms = [line for line in text.splitlines() if line.strip().startswith("j3:")][0]
    before_rms, after_rms = (float(x) for x in rms.split(":")[1].split(",")[0].split("->"))
    assert after_rms < 0.05 * before_rms
    assert "inertia_delta" in written and "inertia_scale" not in written
    # --overwrite replaces a file it wrote; the scale form on two stretches around the push
    code, text, err = identify(capsys, d / "arm", "--params", plant, "--out", out,
                               "--overwrite", "--inertia", "scale", "--segment", "0.2:1.4",
                               "--segment", "1.8:3")
    assert code == 0, err
    assert "inertia_scale" in out.read_text() and "windows left out" not in text
    # the payload after a grasp, the arm's base parameters and friction fixed
    base = d / "base.yaml"
    assert identify(capsys, d / "arm", "--params", plant, "--out", base)[0] == 0
    pay = d / "payload.yaml"
    code, text, err = identify(capsys, d / "grasp", "--params", plant, base, "--out", pay,
                               "--payload-only", "--frame", "l3")
    assert code == 0, err
    s = read(load_params_files([plant, base, pay]))
    assert s["payload.frame"] == "l3" and s["payload.mass"] == pytest.approx(0.7, rel=0.03)
    np.testing.assert_allclose(s["payload.com"], [0.02, -0.03, 0.08], atol=0.01)


def _refusals(d: Path, plant: Path):
    urdf = d / "arm.urdf"
    out = d / "refused.yaml"
    return {
        "no contact-free stretch": (1, [d / "busy", "--params", plant, "--out", out]),
        "no window": (1, [d / "arm", "--params", plant, "--out", out, "--end", "0.05"]),
        "no sample in the stretch": (1, [d / "arm", "--params", plant, "--out", out,
                                         "--start", "100"]),
        "no joint(s) j3": (1, [d / "two_joints", "--params", plant, "--out", out]),
        "carries no efforts": (1, [d / "no_effort", "--params", plant, "--out", out]),
        "not a bag|bag": (1, [d / "arm.urdf", "--params", plant, "--out", out]),
        "invalid choice": (2, [d / "arm", "--params", plant, "--out", out, "--inertia", "all"]),
        "--payload-only needs": (2, [d / "arm", "--params", plant, "--out", out,
                                     "--payload-only"]),
        "only with --inertia scale": (2, [d / "arm", "--params", plant, "--out", out,
                                          "--links", "l1"]),
        "does not exist": (2, [d / "arm", "--params", d / "nope.yaml", "--out", out]),
        "exactly one": (2, [d / "arm", "--params",
                            _plant(d, urdf, "both", robot_description="'<robot/>'"),
                            "--out", out]),
        "the parameter 'joints'": (2, [d / "arm", "--params", _plant(d, urdf, "old", False,
                                                                     plant__joints="[j1]"),
                                       "--out", out]),
        "is the input": (2, [d / "arm", "--params", plant, "--out", d / "arm" / "x.yaml"]),
        "did not write it": (2, [d / "arm", "--params", plant, "--out", urdf, "--overwrite"]),
        "is the input ": (2, [d / "arm", "--params", plant, "--out", plant, "--overwrite"]),
        "exists already": (1, [d / "arm", "--params", plant, "--out", urdf]),
    }


def test_every_refusal_is_one_line_with_its_exit_code(arm, capsys):
    d, plant = arm
    for words, (want, argv) in _refusals(d, plant).items():
        code, text, err = identify(capsys, *argv)
        lines = err.strip().splitlines()
        assert code == want, (words, err)
        assert len(lines) == 1 and lines[0].startswith("fto-identify: error:"), (words, err)
        assert any(w in lines[0] for w in words.split("|")), (words, lines[0])
        assert not (d / "refused.yaml").exists()


def test_the_console_script(arm):
    d, plant = arm
    exe = shutil.which("fto-identify")
    assert exe, "fto-identify is not installed (setup.py console_scripts)"
    done = subprocess.run([exe, str(d / "busy"), "--params", str(plant), "--out",
                           str(d / "script.yaml")], capture_output=True, text=True, timeout=600)
    assert done.returncode == 1 and done.stderr.count("\n") == 1
    assert "no contact-free stretch" in done.stderr and not (d / "script.yaml").exists()
