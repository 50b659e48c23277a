"""Hypothesis's profile for the whole suite, and the fault-injection suite's totals
(test/support/faultkit.py COUNTS: runner operations, command-line runs, live-node operations),
printed in pytest's terminal summary, summed over pytest-xdist's worker processes when
there are several."""
from __future__ import annotations

import pytest
from hypothesis import settings

from faultkit import COUNTS

# Every property test draws the same examples on every run (fuzzing bounded by seed and
# count, not by luck): a failure CI finds is one a developer reproduces, and no run meets
# an example the others never saw. No example database is written into the work tree.
settings.register_profile("fto_ros", derandomize=True, database=None)
settings.load_profile("fto_ros")


def pytest_sessionfinish(session):
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
