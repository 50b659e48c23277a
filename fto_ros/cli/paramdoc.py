"""Print the parameter reference (markdown) from the schemas the code validates against.

``python -m fto_ros.cli.paramdoc`` regenerates the README's parameter tables, so
the docs cannot drift from what the node declares (a test checks the README).
"""
from __future__ import annotations

from ..observers import REGISTRY
from ..observers.base import Param
from ..plant.block import PLANT_PARAMS
from ..runner.settings import SETTINGS
from .simulate_plant import SIM_PARAMS


def _default(p: Param) -> str:
    if p.default is None:
        return "**required**"
    if p.default == [] or p.default == "":
        return "(empty)"
    return f"`{p.default}`"


def _range(p: Param) -> str:
    parts = []
    if p.choices:
        parts.append(" / ".join(p.choices))
    if p.gt is not None:
        parts.append(f"> {p.gt:g}")
    if p.min is not None:
        parts.append(f">= {p.min:g}")
    if p.max is not None:
        parts.append(f"<= {p.max:g}")
    return ", ".join(parts)


def table(params, prefix: str = "") -> str:
    rows = ["| parameter | type | default | range | runtime change | description |",
            "|---|---|---|---|---|---|"]
    for p in params:
        rows.append(f"| `{prefix}{p.name}` | {p.kind} | {_default(p)} | {_range(p)} | "
                    f"{'no' if p.read_only else 'yes'} | {p.description.replace('|', '/')} |")
    return "\n".join(rows)


def main() -> int:
    print("#### Node, runner and I/O parameters\n")
    print(table(SETTINGS))
    print("\n#### `plant` — the plant block, written once; each observer derives its own "
          "parameters from it (docs/plant.md)\n")
    print(table(PLANT_PARAMS, prefix="plant."))
    for name, cls in sorted(REGISTRY.items()):
        print(f"\n#### `{name}` — {cls.DESCRIPTION}\n")
        print(table(cls.PARAMS, prefix=name + "."))
    print("\n#### `simulation` — `fto-simulate --params` (node name `fto_simulate`; "
          "docs/bring_your_own_plant.md)\n")
    print(table(SIM_PARAMS, prefix="simulation."))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
