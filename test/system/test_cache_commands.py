"""The compiled cache seen from whole commands: a full or read-only cache disk runs uncached
and exits 0 with one WARN line (F8: it failed with exit 2, blamed on the tuning); the
read-only deployment (fto-warm-cache once, then FTO_ROS_CACHE_MODE=readonly) reads the
cache and writes nothing (docs/security.md).  Disks are injected (os.open/os.write/os.mkdir
raise ENOSPC or EROFS for paths in the test's cache folder), never a real system path."""
from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config"

#: imported first by the command's process: the cache disk of $FTO_ROS_CACHE fails
INJECT = f"""
import errno, os, sys
sys.path.insert(0, {str(REPO / "test" / "support")!r})
from cache_helpers import failing_calls
for name, fake in failing_calls(getattr(errno, os.environ["FAIL_WITH"]),
                                os.environ["FTO_ROS_CACHE"]).items():
    setattr(os, name, fake)
"""


def run_python(code: str, tmp_path: Path, timeout: float = 900, **env) -> subprocess.CompletedProcess:
    full = dict(os.environ, FTO_ROS_CACHE=str(tmp_path / "cache"))
    full.pop("FTO_ROS_CACHE_MODE", None)
    full.update(env)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=timeout, env=full, cwd=tmp_path)


@pytest.mark.parametrize("fail_with", ["ENOSPC", "EROFS"])
def test_a_full_or_read_only_cache_disk_runs_uncached(tmp_path, fail_with):
    (tmp_path / "inject_disk.py").write_text(INJECT)
    if fail_with == "ENOSPC":                  # the folders are there; the disk is full
        for sub in ("cache", "cache/models"):
            (tmp_path / sub).mkdir(mode=0o700)
    code = ("import sys; sys.path.insert(0, '.'); import inject_disk\n"
            "from fto_ros.cli.design import main\n"
            f"sys.exit(main([{str(CONFIG / 'dc_motor_plant.yaml')!r}, "
            f"{str(CONFIG / 'dc_motor_single_delay.yaml')!r}]))\n")
    res = run_python(code, tmp_path, FTO_ROS_NUMBA="0", FAIL_WITH=fail_with)
    assert res.returncode == 0, res.stderr
    assert "single_delay" in res.stdout
    (line,) = res.stderr.strip().splitlines()
    assert "running uncached" in line and os.strerror(getattr(errno, fail_with)) in line
    assert not any(p.suffix == ".py" for p in (tmp_path / "cache").rglob("*"))


COUNT_LOADS = '''
import sys
from fto_ros.core import compile_cache as CC, jit
loads = {"hit": 0, "miss": 0}
_load = CC.PrivateCache.load_overload
def counted(self, sig, ctx):
    got = _load(self, sig, ctx)
    loads["hit" if got is not None else "miss"] += 1
    return got
CC.PrivateCache.load_overload = counted
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files
Runner(load_params_files(params_files(sys.argv[1])))
print("loads", loads["hit"], loads["miss"])
print(jit.compile_report())
'''


def snapshot(folder: Path) -> dict:
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.rglob("*")}


@pytest.mark.slow
def test_a_warmed_cache_is_only_read_in_read_only_mode(tmp_path):
    config = CONFIG / "dc_motor_luenberger.yaml"
    warm = subprocess.run([sys.executable, "-m", "fto_ros.cli.warm_cache", str(config)],
                          capture_output=True, text=True, timeout=900, cwd=tmp_path,
                          env=dict(os.environ, FTO_ROS_CACHE=str(tmp_path / "cache"),
                                   FTO_ROS_CACHE_MODE="readonly"))
    assert warm.returncode == 0, warm.stderr
    assert "1 of 1 config(s) built" in warm.stdout and warm.stderr == ""
    before = snapshot(tmp_path / "cache")
    assert any(k.endswith(".nbi") for k in before) and any(k.endswith(".py") for k in before)
    (tmp_path / "count_loads.py").write_text(COUNT_LOADS)
    code = "import runpy, sys; sys.argv = ['x', sys.argv[-1]]; runpy.run_path('count_loads.py')"
    res = subprocess.run([sys.executable, "-c", code, str(config)], capture_output=True,
                         text=True, timeout=900, cwd=tmp_path,
                         env=dict(os.environ, FTO_ROS_CACHE=str(tmp_path / "cache"),
                                  FTO_ROS_CACHE_MODE="readonly"))
    assert res.returncode == 0 and res.stderr == "", res.stderr
    hits, misses = (int(v) for v in res.stdout.split("\n")[0].split()[1:])
    assert hits > 0 and misses == 0, res.stdout
    assert "read from the read-only cache" in res.stdout
    assert snapshot(tmp_path / "cache") == before           # nothing written, nothing touched


def test_read_only_mode_without_a_cache_writes_nothing(tmp_path):
    code = ("from fto_ros.runner import Runner\n"
            "from fto_ros.runner.params_file import load_params_files\n"
            "from fto_ros.runner.plant_files import params_files\n"
            f"Runner(load_params_files(params_files({str(CONFIG / 'dc_motor_luenberger.yaml')!r})))\n"
            "print('built')\n")
    res = run_python(code, tmp_path, FTO_ROS_NUMBA="0", FTO_ROS_CACHE_MODE="readonly")
    assert res.returncode == 0 and "built" in res.stdout, res.stderr
    assert not (tmp_path / "cache").exists()
    (line,) = res.stderr.strip().splitlines()
    assert "read-only cache" in line and "fto-warm-cache" in line
