"""The suite's own rules (test/conftest.py, test/support/domains.py, processes.py): a process a
test starts gets default signal handling even when the suite runs with SIGINT ignored (a
background job), its whole group dies with the test or with a timeout; every test that
takes a ROS_DOMAIN_ID gets one no other test holds, from the allowed ranges or
FTO_TEST_DOMAIN_IDS, shared out between pytest-xdist workers; and FTO_ROS_REQUIRE_ROS=1 turns
a skip for a missing ROS piece (only that) into a failure.  No DDS: plain processes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import domains
import processes

TEST = Path(__file__).resolve().parents[1]
#: what a Python child prints: the SIGINT handler it started with
SHOW_SIGINT = [sys.executable, "-c", "import signal; h = signal.getsignal(signal.SIGINT); "
               "print('ignored' if h is signal.SIG_IGN else h.__name__)"]


@pytest.fixture
def fresh_domains(monkeypatch):
    """domains.py's state as a new pytest process has it, restored afterwards."""
    monkeypatch.setattr(domains, "_held", {})
    monkeypatch.setattr(domains, "_state", {"next": 0, "share": None})
    for var in ("FTO_TEST_DOMAIN_IDS", "PYTEST_XDIST_WORKER", "PYTEST_XDIST_WORKER_COUNT"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("ROS_DOMAIN_ID", "7")
    return monkeypatch


def test_every_id_is_allowed_distinct_and_not_the_runs_own(fresh_domains):
    ids = [domains.take() for _ in range(len(domains.ALLOWED) - 1)]
    assert len(set(ids)) == len(ids) == 118
    assert set(ids) == set(domains.ALLOWED) - {7}
    assert set(ids) == (set(range(1, 102)) | set(range(215, 233))) - {7}


def test_the_ids_given_to_the_run_are_the_only_ones_and_held_ones_are_skipped(fresh_domains):
    fresh_domains.setenv("FTO_TEST_DOMAIN_IDS", "215-217,3")
    got = [domains.take() for _ in range(4)]
    assert sorted(got) == [3, 215, 216, 217]
    domains.hold(got[0])
    domains.hold(got[1])
    assert domains.take() not in got[:2]
    for i in got[2:]:
        domains.hold(i)
    with pytest.raises(pytest.fail.Exception, match="held"):
        domains.take()
    domains.release(got[0])
    assert domains.take() == got[0]


def test_xdist_workers_share_the_ids_out(fresh_domains):
    shares = []
    for worker in ("gw0", "gw1"):
        fresh_domains.setattr(domains, "_state", {"next": 0, "share": None})
        fresh_domains.setenv("PYTEST_XDIST_WORKER", worker)
        fresh_domains.setenv("PYTEST_XDIST_WORKER_COUNT", "2")
        shares.append(set(domains.share()))
    assert not shares[0] & shares[1]
    assert shares[0] | shares[1] == set(domains.ALLOWED) - {7}


@pytest.mark.parametrize("spec", ["x-3", "5-400", "9-2"])
def test_a_bad_id_range_is_refused(fresh_domains, spec):
    fresh_domains.setenv("FTO_TEST_DOMAIN_IDS", spec)
    with pytest.raises(pytest.UsageError, match="FTO_TEST_DOMAIN_IDS"):
        domains.take()


def test_a_child_gets_default_sigint_handling_though_the_suite_ignores_it():
    """As under a CI runner's background job: SIGINT ignored here.  A plain Popen's child
    inherits that (the control: this test can fail); spawn's child has the default."""
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        plain = subprocess.run(SHOW_SIGINT, capture_output=True, text=True, timeout=60).stdout
        ours = processes.run(SHOW_SIGINT, capture_output=True, timeout=60).stdout
    finally:
        signal.signal(signal.SIGINT, before)
    assert plain.strip() == "ignored"
    assert ours.strip() == "default_int_handler", ours


def _group_of(pid_file: Path, timeout: float = 10.0) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pid_file.is_file() and pid_file.read_text().strip():
            return int(pid_file.read_text())
        time.sleep(0.02)
    raise AssertionError("the command did not start")


def _running(pgid: int) -> bool:
    return processes._members(pgid)


def test_reap_kills_the_whole_group_grandchildren_too(tmp_path):
    pid_file = tmp_path / "pgid"
    since = processes.mark()
    proc = processes.spawn(["bash", "-c", f"echo $$ > {pid_file}; sleep 300 & sleep 300"])
    pgid = _group_of(pid_file)
    assert pgid == proc.pid and _running(pgid)
    killed = processes.reap(since)
    assert killed and "sleep 300" in killed[0]
    assert not _running(pgid)


def test_interrupt_stops_the_leader_and_kills_what_it_leaves(tmp_path):
    """A leader that exits on SIGINT and leaves a child behind (a launch whose node lives
    on): the child is killed with the group."""
    pid_file = tmp_path / "pgid"
    proc = processes.spawn(["bash", "-c", f"echo $$ > {pid_file}; trap 'exit 0' INT; "
                            "sleep 300 & wait"])
    pgid = _group_of(pid_file)
    time.sleep(0.2)                          # bash's trap in place
    assert processes.interrupt(proc, 10) == 0
    assert not _running(pgid)


def test_a_timeout_kills_the_whole_group(tmp_path):
    pid_file = tmp_path / "pgid"
    with pytest.raises(subprocess.TimeoutExpired):
        processes.run(["bash", "-c", f"echo $$ > {pid_file}; sleep 300 & sleep 300"], timeout=2)
    assert not _running(_group_of(pid_file))


_MODULE_SKIP = "import pytest\npytest.importorskip('fto_fake_msgs')\n\n\ndef test_a():\n    pass\n"
_TEST_SKIP = ("import pytest\n\n\ndef test_b():\n    pytest.importorskip('rclpy_fto_fake')\n\n\n"
              "def test_c():\n    pytest.skip('ROS piece missing: the fto test says so')\n\n\n"
              "def test_d():\n    pytest.importorskip('fto_fake_not_ros')\n")


@pytest.mark.parametrize("required", ["1", "0"])
def test_a_missing_ros_piece_fails_only_when_ros_is_required(tmp_path, required):
    """A module-level and a test-level importorskip of a ROS package, a skip saying a ROS
    piece is missing, and a skip for something else, under test/conftest.py's hooks."""
    (tmp_path / "check_module_level.py").write_text(_MODULE_SKIP)
    (tmp_path / "check_in_tests.py").write_text(_TEST_SKIP)
    env = dict(os.environ, FTO_ROS_REQUIRE_ROS=required,
               PYTHONPATH=os.pathsep.join([str(TEST), str(TEST / "support")]))
    res = subprocess.run([sys.executable, "-m", "pytest", "-p", "conftest", "-p", "no:cacheprovider",
                          "-p", "no:xdist", "-q", "-rfEs", "--rootdir", str(tmp_path),
                          "-o", "python_files=check_*.py", "--continue-on-collection-errors",
                          str(tmp_path)],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    summary = res.stdout.strip().splitlines()[-1]
    if required == "1":
        assert res.returncode == 1, res.stdout
        assert "2 failed" in summary and "1 skipped" in summary and "1 error" in summary, res.stdout
        assert "FTO_ROS_REQUIRE_ROS=1, and a ROS piece is missing" in res.stdout
    else:
        assert res.returncode == 0, res.stdout
        assert "4 skipped" in summary, res.stdout
