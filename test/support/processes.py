"""Processes a test starts (nodes, `ros2 launch`, fto-play, colcon's installed node): each in
a session of its own with the default handling of SIGINT and SIGTERM, stopped like Ctrl-C
stops it in a terminal (SIGINT to its whole process group), and killed with its whole group
whatever happens to the test.

Why: a suite started as a background job (a CI runner, a service manager, `cmd &`) has
SIGINT ignored, and a child inherits that: `ros2 launch` then ignored its Ctrl-C, was killed
with SIGKILL, and its node lived on, publishing /diagnostics on the test's domain and
holding shared-memory port locks that failed later live tests.  So:
- ``spawn`` starts the command with ``start_new_session=True`` (its own process group: the
  group can be signalled and killed as one) and a ``preexec_fn`` that puts SIGINT, SIGTERM
  (and SIGQUIT) back to SIG_DFL before exec: the child's own handlers (rclpy's, launch's)
  are installed as on a terminal;
- ``interrupt`` sends SIGINT to the leader, waits, then SIGKILLs what is left of the group;
- ``reap`` kills every group started since a ``mark()`` that still has a member:
  test/conftest.py reaps what a test started after the test (passed, failed or errored),
  what a module's fixtures started after the module, and everything before pytest-timeout
  ends a test that hangs, so nothing a test started outlives it;
- ``run`` is ``subprocess.run`` with the same session, signals and reaping (a timeout kills
  the group, not just the leader).
"""
from __future__ import annotations

import os
import signal
import subprocess
import time

import domains

#: (sequence number, process, domain or None) of every group started and not yet reaped
_started: list[tuple[int, subprocess.Popen, int | None]] = []
_count = [0]


def _default_signals() -> None:
    """In the child, before exec: the signals a background job ignores, back to default."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGQUIT):
        signal.signal(sig, signal.SIG_DFL)


def spawn(cmd, *, domain: int | None = None, **kwargs) -> subprocess.Popen:
    """``subprocess.Popen(cmd, **kwargs)`` in a new session with default signal handling;
    ``domain`` (its ROS_DOMAIN_ID) is held until the group is gone."""
    proc = subprocess.Popen(cmd, start_new_session=True, preexec_fn=_default_signals, **kwargs)
    _started.append((_count[0], proc, domain))
    _count[0] += 1
    if domain is not None:
        domains.hold(domain)
    return proc


def group_alive(proc: subprocess.Popen) -> bool:
    """Whether any process of ``proc``'s group (its session) is still running."""
    if proc.poll() is None:
        return True
    try:
        os.killpg(proc.pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:           # a member that changed its uid: still there
        return True
    # an orphan's zombie (a container's init may never reap it) keeps the group id
    return _members(proc.pid)


def _members(pgid: int) -> bool:
    """Whether a process other than a zombie is in group ``pgid``."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL to the whole group; wait for the leader and until no member runs."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        pass
    wait_gone(proc, 10)


def interrupt(proc: subprocess.Popen, timeout: float = 30.0) -> int | None:
    """SIGINT to the leader (`kill -INT`: `ros2 launch` forwards it to its nodes), wait up
    to ``timeout`` s for it; then SIGKILL to whatever is left of the group.  The leader's
    exit code (negative: killed by a signal).

    Not SIGINT to the whole group, as a terminal's Ctrl-C does: a node under `ros2 launch`
    would get it twice (the terminal's, then launch's), and the second one, arriving while
    the node tears down, ends it with a KeyboardInterrupt traceback (seen with
    arm7.launch.py)."""
    if proc.poll() is None:
        try:
            proc.send_signal(signal.SIGINT)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            pass
    code = proc.returncode
    if group_alive(proc):
        kill_group(proc)
    _forget(proc)
    return code if code is not None else proc.returncode


def _forget(proc: subprocess.Popen) -> None:
    for i, (_, p, domain) in enumerate(_started):
        if p is proc:
            del _started[i]
            if domain is not None:
                domains.release(domain)
            return


def mark() -> int:
    """A token for ``reap``: the groups started from now on."""
    return _count[0]


def reap(since: int = 0) -> list[str]:
    """Kill every group started here (since the ``mark()`` ``since``) that still has a member;
    what was killed (commands)."""
    killed = []
    for seq, proc, _ in list(_started):
        if seq < since:
            continue
        if group_alive(proc):
            killed.append(" ".join(map(str, proc.args))[:200])
            kill_group(proc)
        _forget(proc)
    return killed


def run(cmd, *, timeout: float, domain: int | None = None, input: str | None = None,
        **kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, timeout=timeout, text=True, **kwargs)`` in a new session with
    default signals; a timeout kills the whole group and raises TimeoutExpired."""
    kwargs.setdefault("text", True)
    if kwargs.pop("capture_output", False):
        kwargs.update(stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if input is not None:
        kwargs["stdin"] = subprocess.PIPE
    proc = spawn(cmd, domain=domain, **kwargs)
    try:
        out, err = proc.communicate(input, timeout=timeout)
    except subprocess.TimeoutExpired:
        kill_group(proc)
        proc.communicate()
        _forget(proc)
        raise
    if group_alive(proc):             # the command is done; what it left behind is not
        kill_group(proc)
    _forget(proc)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def wait_gone(proc: subprocess.Popen, timeout: float) -> bool:
    """Wait until ``proc``'s group has no member left (True) or ``timeout`` s pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not group_alive(proc):
            return True
        time.sleep(0.05)
    return False
