"""``fto-design`` on a per-joint plant: ``joints`` with constants ``'name=[v1, ..., vJ]'``
(config/arm7_plant.yaml), one plant per joint.

The plant block is the model of ONE joint; each joint's plant has its own value of every
per-joint constant (runner/joints.py).  Printed: the joints and a table of the per-joint
constants; the first joint's plant; which observer types apply (to every joint, or to
which); per applicable type the first joint's derivation in full and a joint table of each
derived value or figure that differs between joints; per tuning file the observers built
for every joint (the runner builds them as the node does): the first joint's design figures
and a joint table of those that differ.
"""
from __future__ import annotations

import sys
from typing import Any, Mapping, Sequence

from ..core.errors import ConfigError


def _table(label: str, joints: Sequence[str], values: Sequence[str]) -> list[str]:
    width = max(len(j) for j in joints)
    return [f"  {label} per joint:"] + [f"    {j:<{width}}  {v}" for j, v in zip(joints, values)]


def _differing(joints, items: Sequence[Mapping[str, Any]], fmt) -> list[str]:
    """A joint table of each key whose value differs between the joints' mappings."""
    lines: list[str] = []
    for key in items[0]:
        vals = [fmt(key, it.get(key)) for it in items]
        if len(set(vals)) > 1:
            lines += _table(key, joints, vals)
    return lines


def _param_text(type_name: str, plant, d) -> Any:
    from ..plant.design import derivation_lines
    return derivation_lines(type_name, d, plant)


def design_joints(base: dict, tunings: list, joints: list[str], out, prog: str) -> int:
    """Print the per-joint design (the module doc); returns the exit code."""
    from ..plant import resolve_plant
    from ..plant.derive import Derivation
    from ..plant.design import (applicability_lines, classify, derivation_lines, observer_lines,
                                plant_lines)
    from ..runner import Runner
    from ..runner import joints as JX
    flats = JX.per_joint(base, joints)
    plants = [resolve_plant(f) for f in flats]

    def section_of(flat):
        return lambda t: {k[len(t) + 1:]: v for k, v in flat.items() if k.startswith(t + ".")}

    results = [classify(pl, section_of(f)) for pl, f in zip(plants, flats)]
    per_joint_constants = [t for t in base.get("plant.constants") or []
                           if isinstance(t, str) and t.partition("=")[2].strip().startswith("[")]
    lines = [f"per-joint plant: {len(joints)} joints ({', '.join(joints)}), one observer of "
             "this plant per joint"]
    if per_joint_constants:
        consts = [dict(c.split("=", 1) for c in f.get("plant.constants") or []) for f in flats]
        names = [t.partition("=")[0].strip() for t in per_joint_constants]
        lines += _table("constants (" + ", ".join(names) + ")", joints,
                        [", ".join(f"{n}={c[n].strip()}" for n in names) for c in consts])
    lines += ["", f"the plant of {joints[0]}:"] + plant_lines(plants[0])
    first = results[0]
    verdicts = {t: [isinstance(r[t], Derivation) for r in results] for t in first}
    lines += applicability_lines(first)
    for t, ok in verdicts.items():
        if len(set(ok)) > 1:
            lines.append(f"  {t}: applies to {', '.join(j for j, o in zip(joints, ok) if o)} "
                         "only")
    for t, r in first.items():
        if not isinstance(r, Derivation):
            continue
        lines += derivation_lines(t, r, plants[0], f" ({joints[0]})")
        ds = [res[t] for res in results]
        if all(isinstance(d, Derivation) for d in ds):
            items = [{**d.params, **d.figures} for d in ds]
            lines += _differing(joints, items, lambda k, v: _short(v))
    print("\n".join(lines), file=out)
    rc = 0
    for path, flat in tunings:
        merged = {**base, **flat}
        type_name = flat["observer.type"]
        try:
            runner = Runner(merged)
        except ConfigError as exc:
            print(f"{prog}: error: {path}: {exc}", file=sys.stderr)
            rc = 2
            continue
        obs = runner.observers
        block = observer_lines(f"{type_name} ({path.name}), {joints[0]}", obs[0])
        diags = [{"guaranteed time": str(o.guaranteed_time), **{k: str(v) for k, v in
                                                             o.diagnostics().items()}}
                 for o in obs]
        block += _differing(joints, diags, lambda k, v: str(v))
        print("\n".join(block), file=out)
    return rc


def _short(v: Any) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(f"{x:.6g}" if isinstance(x, float) else str(x) for x in v) + "]"
    return f"{v:.6g}" if isinstance(v, float) else str(v)
