"""Tables of expectations keyed by observer family, for tests that iterate over
fto_ros.observers.REGISTRY: a family registered without an entry fails, naming the table,
so a new family cannot go untested."""
from __future__ import annotations

import pytest


def expected(table: dict, family: str, table_name: str, what: str):
    """``table[family]``, or a failure saying that ``family`` is registered but has no entry
    in ``table_name`` and what the entry gives."""
    if family not in table:
        pytest.fail(f"observer family {family!r} is registered but has no entry in "
                    f"{table_name}: {what}")
    return table[family]
