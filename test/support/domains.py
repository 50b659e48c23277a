"""ROS_DOMAIN_IDs for the tests that start DDS participants: each call of ``take()`` hands
out an id that no other test of this run holds, so a node a failed test left behind (or
its /diagnostics, its shared-memory port locks) can never reach the next test.

The ids come from the ranges every DDS vendor takes (Fast DDS computes its ports from the
id: 1-101 and 215-232 stay below the ephemeral ports), or from FTO_TEST_DOMAIN_IDS
(``LO-HI[,LO-HI...]``, e.g. ``215-220``: the ids a shared machine gives this run).  The id
scripts/run-tests exports for the run as a whole (ROS_DOMAIN_ID) is left out: processes that
take no id of their own use it.  pytest-xdist workers share the pool out (worker i of n takes
every n-th id), and the ids are handed out in turn from an offset of the run (the run's
ROS_DOMAIN_ID), so two runs side by side start apart; an id is handed out again only after
the whole share has been, and never while a live process of this run still holds it
(``hold``/``release``, which test/support/processes.py and the live-node driver call).
"""
from __future__ import annotations

import os

import pytest

#: the ids a test may use when FTO_TEST_DOMAIN_IDS does not say
ALLOWED = tuple(range(1, 102)) + tuple(range(215, 233))

_held: dict[int, int] = {}
_state = {"next": 0, "share": None}


def _parse(spec: str) -> tuple[int, ...]:
    ids: list[int] = []
    for part in spec.split(","):
        lo, _, hi = part.strip().partition("-")
        try:
            first, last = int(lo), int(hi or lo)
        except ValueError:
            raise pytest.UsageError(f"FTO_TEST_DOMAIN_IDS={spec!r}: expected LO-HI[,LO-HI...]")
        if not (0 <= first <= last <= 232):
            raise pytest.UsageError(f"FTO_TEST_DOMAIN_IDS={spec!r}: ids are 0..232")
        ids += range(first, last + 1)
    return tuple(dict.fromkeys(ids))


def share() -> tuple[int, ...]:
    """The ids this process may hand out (see the module docstring)."""
    if _state["share"] is None:
        spec = os.environ.get("FTO_TEST_DOMAIN_IDS")
        pool = _parse(spec) if spec else ALLOWED
        run_id = os.environ.get("ROS_DOMAIN_ID", "")
        if not spec and run_id.isdigit():
            pool = tuple(i for i in pool if i != int(run_id))
        worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
        count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
        index = int(worker[2:]) if worker[2:].isdigit() else 0
        mine = pool[index % count::count] if count > 1 and len(pool) >= count else pool
        start = int(run_id) % len(mine) if run_id.isdigit() else 0
        _state["share"] = mine[start:] + mine[:start]
    return _state["share"]


def take() -> int:
    """A domain id no live process of this run holds, the next of this process's share."""
    ids = share()
    for i in range(len(ids)):
        domain = ids[(_state["next"] + i) % len(ids)]
        if not _held.get(domain):
            _state["next"] = (_state["next"] + i + 1) % len(ids)
            return domain
    pytest.fail(f"every domain id of {ids} is held by a live process of this run")


def hold(domain: int) -> None:
    _held[domain] = _held.get(domain, 0) + 1


def release(domain: int) -> None:
    _held[domain] = max(0, _held.get(domain, 0) - 1)
