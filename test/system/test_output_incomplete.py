"""An output that could not be completed (the disk filling up mid-write, injected as
ENOSPC) is never left looking like a finished one (F19: a marked folder with a partial
.mcap and no metadata.yaml): a bag output is removed, a sweep's or a report's is renamed
``<out>.incomplete-<pid>`` with its marker saying so; the command exits 1 with one line."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config"
NOMINAL = REPO / "bags" / "dc_motor_nominal"
SINGLE_DELAY = REPO / "test" / "data" / "dc_motor_explicit" / "dc_motor_single_delay.yaml"

#: imported first: files opened for writing under $ENOSPC_DIR whose name matches
#: $ENOSPC_NAME (default: all) get $ENOSPC_BYTES bytes in all, then every write raises ENOSPC
INJECT = '''
import builtins, errno, fnmatch, io, os
_DIR = os.path.realpath(os.environ["ENOSPC_DIR"])
_NAME = os.environ.get("ENOSPC_NAME", "*")
_left = [int(os.environ.get("ENOSPC_BYTES", "0"))]
_open = io.open

class _Full(io.RawIOBase):
    def __init__(self, raw):
        self._raw = raw
    def writable(self):
        return True
    def write(self, b):
        n = len(memoryview(b).cast("B"))
        if n > _left[0]:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        _left[0] -= n
        return self._raw.write(b)
    def close(self):
        if not self.closed:
            try:
                super().close()
            finally:
                self._raw.close()
    def fileno(self):
        return self._raw.fileno()
    def seekable(self):
        return self._raw.seekable()
    def seek(self, *a):
        return self._raw.seek(*a)
    def tell(self):
        return self._raw.tell()

def _patched(file, mode="r", buffering=-1, encoding=None, errors=None, newline=None,
             closefd=True, opener=None):
    if isinstance(file, (str, bytes, os.PathLike)) and any(c in mode for c in "wxa+"):
        path = os.path.realpath(os.fsdecode(file))
        if path.startswith(_DIR + os.sep) and fnmatch.fnmatch(os.path.basename(path), _NAME):
            raw = _Full(_open(file, mode.replace("t", "").replace("b", "") + "b", buffering=0))
            f = io.BufferedWriter(raw)
            return f if "b" in mode else io.TextIOWrapper(f, encoding=encoding or "utf-8",
                                                         errors=errors, newline=newline)
    return _open(file, mode, buffering, encoding, errors, newline, closefd, opener)

io.open = builtins.open = _patched
'''


def run(tmp_path: Path, module: str, args: list[str], name: str = "*",
        quota: int = 0) -> subprocess.CompletedProcess:
    (tmp_path / "inject_full.py").write_text(INJECT)
    code = (f"import sys; sys.path.insert(0, '.'); import inject_full\n"
            f"from {module} import main\nsys.exit(main(sys.argv[1:]))\n")
    env = dict(os.environ, ENOSPC_DIR=str(tmp_path / "outs"), ENOSPC_NAME=name,
               ENOSPC_BYTES=str(quota))
    (tmp_path / "outs").mkdir(exist_ok=True)
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=900, env=env, cwd=tmp_path)


def one_error_line(res, prog: str) -> str:
    assert res.returncode == 1, res.stderr
    lines = [ln for ln in res.stderr.strip().splitlines() if not ln.startswith(f"{prog}: [")]
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert lines[0].startswith(f"{prog}: error: ") and "No space left on device" in lines[0]
    return lines[0]




@pytest.mark.parametrize("where,name,quota", [
    ("mid-bag", "*.mcap", 20000),
    ("finishing the bag", "metadata.yaml*", 0),
    ("the metrics", "metrics.json", 0),
])
def test_a_replay_that_cannot_finish_leaves_no_output(tmp_path, where, name, quota):
    out = tmp_path / "outs" / "replay"
    res = run(tmp_path, "fto_ros.replay.cli",
              [str(NOMINAL), "--params", str(SINGLE_DELAY), "--out", str(out)], name, quota)
    line = one_error_line(res, "fto-replay")
    assert not os.path.lexists(out), (where, line)
    assert list((tmp_path / "outs").iterdir()) == []


def test_a_simulation_that_cannot_finish_leaves_no_bag(tmp_path):
    out = tmp_path / "outs" / "sim"
    res = run(tmp_path, "fto_ros.cli.simulate", ["dc_motor", "--duration", "2", "--out",
                                                 str(out)], "*.mcap", 30000)
    one_error_line(res, "fto-simulate")
    assert list((tmp_path / "outs").iterdir()) == []


def renamed(tmp_path: Path, out: Path, kind: str) -> Path:
    assert not os.path.lexists(out)
    (left,) = list((tmp_path / "outs").iterdir())
    assert left.name.startswith(f"{out.name}.incomplete-")
    marker = json.loads((left / ".fto_ros_output").read_text())
    assert marker["kind"] == kind and "No space left" in marker["incomplete"]
    return left


def test_a_sweep_whose_results_cannot_be_written_is_renamed(tmp_path):
    out = tmp_path / "outs" / "sweep"
    res = run(tmp_path, "fto_ros.sweep.cli",
              ["--params", str(SINGLE_DELAY), "--bag", str(NOMINAL), "--set",
               "single_delay.k=100,120", "--out", str(out), "--workers", "1", "--quiet",
               "--no-plots"], "results.csv", 100)
    line = one_error_line(res, "fto-sweep")
    left = renamed(tmp_path, out, "sweep")
    assert str(left) in line


@pytest.mark.slow
def test_a_report_that_cannot_be_written_is_renamed(tmp_path):
    configs, bags = tmp_path / "config", tmp_path / "bags"
    configs.mkdir()
    bags.mkdir()
    for name in ("dc_motor_plant.yaml", "dc_motor_luenberger.yaml"):
        (configs / name).write_text((CONFIG / name).read_text())
    (bags / NOMINAL.name).symlink_to(NOMINAL)
    out = tmp_path / "outs" / "report"
    res = run(tmp_path, "fto_ros.cli.report",
              ["--out", str(out), "--bags-dir", str(bags), "--config-dir", str(configs),
               "--workers", "1", "--no-progress"], "report.md", 0)
    assert res.returncode == 1, res.stderr
    # (the report's other lines: the bags of this system that the test does not provide)
    (line,) = [ln for ln in res.stderr.splitlines() if "report.md" in ln]
    assert line.startswith("fto-report: error: cannot write") and "No space left" in line
    assert "Traceback" not in res.stderr
    left = renamed(tmp_path, out, "report")
    assert str(left) in line
