"""fto-sweep's --scheduler errors (F17) end in their one line within --connect-timeout, with
no traceback, not even at the interpreter's exit (where distributed's half-built Client
printed one 60 s later); a local sweep leaves no semaphore behind (the resource tracker's
"leaked semaphore objects" warning)."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from fto_ros.sweep import cli
from fto_ros.sweep.cluster import EngineError, split_address

REPO = Path(__file__).resolve().parents[3]
NOMINAL = REPO / "bags" / "dc_motor_nominal"
SINGLE_DELAY = REPO / "test" / "data" / "dc_motor_explicit" / "dc_motor_single_delay.yaml"


@pytest.mark.parametrize("address", ["zzz://127.0.0.1:1", "inproc://x/1/2", "tcp://h:99999",
                                     "tcp://h", "tcp://:8786", "ucx://h:1", "tcp://h:1/path"])
def test_addresses_other_than_a_networked_scheduler_are_usage_errors(address, capsys):
    with pytest.raises(EngineError):
        split_address(address)
    with pytest.raises(SystemExit) as exc:
        cli.main(["--params", str(SINGLE_DELAY), "--bag", str(NOMINAL), "--out", "never",
                  "--scheduler", address])
    assert exc.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("fto-sweep: error: argument --scheduler")


def test_networked_addresses_are_read():
    assert split_address("tcp://127.0.0.1:8786") == ("tcp", "127.0.0.1", 8786)
    assert split_address("tls://[::1]:8786") == ("tls", "::1", 8786)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Silent:
    """A port on 127.0.0.1 that accepts connections and never says anything."""

    def __enter__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.conns = []
        threading.Thread(target=self._accept, daemon=True).start()
        return self.sock.getsockname()[1]

    def _accept(self):
        try:
            while True:
                self.conns.append(self.sock.accept()[0])
        except OSError:
            pass

    def __exit__(self, *exc):
        for c in self.conns:
            c.close()
        self.sock.close()


def sweep(tmp_path, address: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "fto_ros.sweep.cli", "--params", str(SINGLE_DELAY), "--bag",
         str(NOMINAL), "--out", str(tmp_path / "out"), "--quiet", "--scheduler", address,
         "--connect-timeout", "2"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path)


@pytest.mark.parametrize("case", ["refused", "silent", "unknown host"])
def test_an_unreachable_scheduler_is_one_line_and_exit_1(tmp_path, case):
    pytest.importorskip("distributed")
    if case == "silent":
        with Silent() as port:
            res = sweep(tmp_path, f"tcp://127.0.0.1:{port}")
        words = "no Dask scheduler answers"
    else:
        address = (f"tcp://127.0.0.1:{free_port()}" if case == "refused"
                   else "tcp://no-such-host.invalid:8786")
        res = sweep(tmp_path, address)
        words = "cannot connect to the Dask scheduler"
    assert res.returncode == 1, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith(f"fto-sweep: error: {words}") and "connect timeout 2 s" in line
    assert not (tmp_path / "out").exists()


#: a sitecustomize for the sweep's processes: every semaphore registered with, and
#: unregistered from, the resource tracker, by process
TRACK = '''
import os
from multiprocessing import resource_tracker as rt
_reg, _unreg = rt.register, rt.unregister
def _note(what, name, rtype):
    with open(os.environ["SEM_LOG"], "a") as f:
        f.write(f"{what} {rtype} {name}\\n")
def register(name, rtype):
    _note("REG", name, rtype)
    return _reg(name, rtype)
def unregister(name, rtype):
    _note("UNREG", name, rtype)
    return _unreg(name, rtype)
rt.register, rt.unregister = register, unregister
'''


@pytest.mark.slow
def test_a_local_sweep_leaves_no_semaphore(tmp_path):
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "sitecustomize.py").write_text(TRACK)
    log = tmp_path / "semaphores.txt"
    env = dict(os.environ, PYTHONPATH=str(tmp_path / "site"), SEM_LOG=str(log))
    res = subprocess.run(
        [sys.executable, "-m", "fto_ros.sweep.cli", "--params", str(SINGLE_DELAY), "--bag",
         str(NOMINAL), "--set", "single_delay.k=100,120,140", "--set",
         "single_delay.tau=0.05,0.1", "--out", str(tmp_path / "out"), "--quiet",
         "--workers", "2", "--no-plots"],
        capture_output=True, text=True, timeout=900, cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stderr
    assert "leaked" not in res.stderr and "resource_tracker" not in res.stderr, res.stderr
    entries = [line.split() for line in log.read_text().splitlines()]
    registered = {name for what, _, name in entries if what == "REG"}
    unregistered = {name for what, _, name in entries if what == "UNREG"}
    assert registered and registered == unregistered
