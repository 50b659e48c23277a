"""The whole suite's rules (the shared helpers are in test/support/, on the path by pytest.ini):
- Hypothesis's profile: derandomized, no example database;
- every process a test started (test/support/processes.py) is killed with its process group
  when the test ends, whether it passed, failed or errored, and before pytest-timeout ends
  a test that hangs (its thread method exits the process: no finalizer would run);
- FTO_ROS_REQUIRE_ROS=1 (scripts/run-tests sets it): a test that would be skipped because a
  ROS piece is missing (rclpy, a message package, the ros2 command line) fails instead, so a
  CI machine without them cannot pass by skipping the ROS tests; without the variable (a
  developer's bare `pytest`) they skip, with the reason;
- the fault-injection suite's totals (test/support/faultkit.py COUNTS: runner operations,
  command-line runs, live-node operations), printed in pytest's terminal summary, summed
  over pytest-xdist's worker processes when there are several."""
from __future__ import annotations

import os
import re
import threading

import pytest
from hypothesis import settings

import processes
from faultkit import COUNTS

# Every property test draws the same examples on every run (fuzzing bounded by seed and
# count, not by luck): a failure CI finds is one a developer reproduces, and no run meets
# an example the others never saw. No example database is written into the work tree.
settings.register_profile("fto_ros", derandomize=True, database=None)
settings.load_profile("fto_ros")

#: a skip reason that names a missing ROS piece: pytest.importorskip of rclpy, an rcl or
#: message package, launch; the ros2 command line (test/support/ros2_cli.py); any skip whose
#: reason says "ROS piece missing"
ROS_SKIP = re.compile(r"could not import '(rclpy|rcl\w*|\w+_(msgs|srvs|interfaces)|launch\w*|ros2\w*)'"
                      r"|ROS 2 command-line tools|ROS piece missing")


def ros_required() -> bool:
    return os.environ.get("FTO_ROS_REQUIRE_ROS", "") not in ("", "0")


def _skip_reason(longrepr) -> str:
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2])
    return str(longrepr)


def _ros_skip_fails(report) -> None:
    """Turn a skip for a missing ROS piece into a failure (FTO_ROS_REQUIRE_ROS=1)."""
    if report.skipped and ros_required() and not hasattr(report, "wasxfail"):
        reason = _skip_reason(report.longrepr)
        if ROS_SKIP.search(reason):
            report.outcome = "failed"
            report.longrepr = f"FTO_ROS_REQUIRE_ROS=1, and a ROS piece is missing: {reason}"


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    _ros_skip_fails(outcome.get_result())          # a module-level importorskip("rclpy")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _ros_skip_fails(outcome.get_result())


@pytest.fixture(autouse=True)
def _reap_processes():
    """Kill what the test started and left (its process groups), pass or fail; a module
    fixture's node, started before, lives on to the module's end."""
    since = processes.mark()
    yield
    processes.reap(since)


@pytest.fixture(autouse=True, scope="module")
def _reap_module_processes():
    """Kill what a module's fixtures started, at the module's end."""
    since = processes.mark()
    yield
    processes.reap(since)


@pytest.hookimpl(tryfirst=True)
def pytest_timeout_set_timer(item, settings):
    """pytest-timeout's thread method ends the whole process (os._exit) when a test hangs:
    kill the test's process groups first, then let it report and exit."""
    if settings.method != "thread":
        return None
    import pytest_timeout

    def expire():
        processes.reap()
        pytest_timeout.timeout_timer(item, settings)
    timer = threading.Timer(settings.timeout, expire)
    timer.name = f"fto_ros timeout {item.nodeid}"
    timer.daemon = True

    def cancel():
        timer.cancel()
        timer.join()
    item.cancel_timeout = cancel
    timer.start()
    return True


def pytest_sessionfinish(session):
    processes.reap()                               # module fixtures' nodes, if any are left
    if hasattr(session.config, "workeroutput"):           # an xdist worker: hand them over
        session.config.workeroutput["fault_counts"] = dict(COUNTS)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):                     # xdist controller: add them up
    COUNTS.update(getattr(node, "workeroutput", {}).get("fault_counts", {}))


def pytest_terminal_summary(terminalreporter):
    cli = {k[4:]: v for k, v in COUNTS.items() if k.startswith("cli_")}
    live = {k[5:]: v for k, v in COUNTS.items() if k.startswith("live_")}
    runner = {k: v for k, v in COUNTS.items() if not k.startswith(("cli_", "live_"))}
    for what, unit, counts in (("runner", "operations", runner),
                               ("command line", "runs", cli),
                               ("live node", "operations", live)):
        if counts:
            terminalreporter.write_line(
                f"fault injection ({what}): {sum(counts.values())} {unit}, by family: "
                + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
