"""The real ROS 2 Jazzy command line for the tests: `ros2 launch`, `ros2 param`, `ros2 lifecycle`.

The command line exists neither on PyPI nor in Debian; a folder of its Jazzy sources with an
install script (README.md there) is looked for in FTO_ROS2_TOOLS, else <repo>/../shared/ros2-tools,
else <repo>/../../shared/ros2-tools (a git worktree one folder further down).  Its install.sh puts `ros2`, launch and launch_ros on top of the
venv's rclpy, here into <venv>/ros2-tools: kept with the venv (the script returns at once once
done), so CI installs it once per venv, ~1 min.  A test that needs it skips, naming the folders
looked in, where none exists (a user's clone without it).

`ros2 launch fto_ros X` and launch_ros's Node(package='fto_ros', ...) find the package through
an ament prefix, which a colcon install provides; `ament_prefix()` lays one out in a temporary
folder as colcon would (share/ament_index marker, share/fto_ros/{launch,config,package.xml}
linked to the repo's, lib/fto_ros/<executable> linked to the venv's console scripts), so the
launch files under test are the work tree's own.
"""
from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

import pytest

import processes

ROOT = Path(__file__).resolve().parents[2]
VENV = Path(sys.prefix)
#: where install.sh puts the tools (inside the venv: cached with it)
DEST = VENV / "ros2-tools"
#: verbs that would otherwise start (and leave running) a ros2 daemon
_DAEMON_VERBS = {"param", "node", "lifecycle", "topic", "service"}
_NO_DAEMON_SUBVERBS = {"call", "pub", "bw", "delay", "hz"}     # these take no --no-daemon
EXECUTABLES = ("observer_node", "managed_observer_node")
EXECUTABLES += ("external_torque_node",)       # test/system/test_arm_node_live.py


def candidates() -> list[Path]:
    """FTO_ROS2_TOOLS, else shared/ros2-tools beside the clone, or beside the folder of a
    git worktree (worktrees/<name> next to shared/)."""
    env = os.environ.get("FTO_ROS2_TOOLS")
    return ([Path(env)] if env else []) + [ROOT.parent / "shared" / "ros2-tools",
                                           ROOT.parent.parent / "shared" / "ros2-tools"]


@lru_cache(maxsize=None)
def _install() -> tuple[Path | None, str]:
    """(the ros2 command, "") or (None, why not)."""
    src = next((c for c in candidates() if (c / "install.sh").is_file()), None)
    if src is None:
        return None, ("the ROS 2 command-line tools are not here (looked in "
                      + ", ".join(map(str, candidates())) + "; set FTO_ROS2_TOOLS)")
    DEST.mkdir(exist_ok=True)
    with open(VENV / ".ros2-tools.lock", "w") as lock:      # one installer at a time
        fcntl.flock(lock, fcntl.LOCK_EX)
        res = subprocess.run(["bash", str(src / "install.sh"), sys.executable, str(DEST)],
                             capture_output=True, text=True, timeout=900)
    if res.returncode != 0:
        pytest.fail(f"{src}/install.sh failed ({res.returncode}):\n{res.stdout}{res.stderr}")
    return DEST / "bin" / "ros2", ""


def ros2_command() -> Path:
    """The `ros2` command (installed on first use); skips the test where the tools are absent."""
    cmd, why = _install()
    if cmd is None:
        pytest.skip(why)
    return cmd


def ament_prefix(folder: Path) -> Path:
    """A colcon-like install prefix of fto_ros in ``folder`` (see the module docstring)."""
    share = folder / "share"
    index = share / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True, exist_ok=True)
    (index / "fto_ros").write_text("")
    pkg = share / "fto_ros"
    # folders of links to the files (ros2 launch walks the share folder without following
    # a linked folder)
    for sub in ("launch", "config"):
        (pkg / sub).mkdir(parents=True, exist_ok=True)
        for f in sorted((ROOT / sub).iterdir()):
            if f.is_file() and not (pkg / sub / f.name).exists():
                (pkg / sub / f.name).symlink_to(f)
    if not (pkg / "package.xml").exists():
        (pkg / "package.xml").symlink_to(ROOT / "package.xml")
    lib = folder / "lib" / "fto_ros"
    lib.mkdir(parents=True, exist_ok=True)
    for exe in EXECUTABLES:
        if not (lib / exe).exists():
            (lib / exe).symlink_to(VENV / "bin" / exe)
    return folder


def env_for(env: dict, prefix: Path) -> dict:
    """``env`` with the ament prefix of fto_ros (then the venv's message packages) and the
    venv first on PATH."""
    out = dict(env)
    out["AMENT_PREFIX_PATH"] = os.pathsep.join([str(prefix), str(VENV)])
    out["PATH"] = os.pathsep.join([str(VENV / "bin"), out.get("PATH", "")])
    return out


def _direct(args) -> bool:
    """Whether the verb discovers the graph itself (a direct node, no daemon)."""
    return bool(args) and args[0] in _DAEMON_VERBS and len(args) > 1 \
        and args[1] not in _NO_DAEMON_SUBVERBS


def argv(*args: str, spin: float | None = None) -> list[str]:
    """The `ros2` command line for ``args``, with --no-daemon where the verb takes it (and
    --spin-time SPIN: how long its node waits for discovery)."""
    cmd = [str(ros2_command()), *args]
    if _direct(args):
        cmd.append("--no-daemon")
        if spin is not None:
            cmd += ["--spin-time", str(spin)]
    return cmd


def run(env: dict, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """Run `ros2 ARGS` (stdout and stderr together, text).  A verb's node spins 0.5 s for
    discovery before it looks the node up; on a loaded machine that can be too short
    ("Node not found"): then again, waiting 2 s, then 8 s."""
    for spin in (None, 2.0, 8.0):
        res = processes.run(argv(*args, spin=spin), env=env, cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, timeout=timeout)
        if not (_direct(args) and res.stdout.strip() == "Node not found"):
            break
    return res
