"""What a source publishes per sample: its output plan, as data (ROS-free).

An output (:class:`OutputSpec`) is a topic relative to the node, a message type, and per
entry (an element of a Float64MultiArray, a name of a JointState) its label, the joint row
it comes from, and per value array the runner output it is gathered from: ``x`` (the
estimate), ``w`` (the unknown-input estimate) or ``c`` (the convergence values; a
non-finite one, i.e. guaranteed_time = inf, "no guarantee", is published as -1) and the
column.  A message holds the entries whose joint has an output for that sample (a joint
whose sample was rejected or held is left out, never published with an old or non-finite
value); the whole plant is one row, always there.

- the whole plant (``topics``, ``joint_states``): ``state_estimate`` / ``convergence`` /
  ``unknown_input_estimate`` (Float64MultiArray, one labelled dimension per element),
  ``state_estimate_stamped`` / ``unknown_input_estimate_stamped`` (JointState: name =
  the names, position = the values), ``estimated_joint_states`` when
  ``estimated_joint_states.joint_names`` maps the estimate onto joints;
- per joint (``joints``): ``estimated_joint_states`` (each joint's position, velocity and
  effort by the runner's roles, runner/joints.py), the same Float64MultiArrays and stamped
  JointStates labelled ``joint/element``.

:meth:`OutputPlan.encode_block` encodes K samples of one output at once (the replay);
:meth:`OutputPlan.encode_one` one sample into a reused buffer (the node): the same layouts
from core/cdr.py.  ``targets`` say what ``~/set_state`` sets: per joint row a key (the
whole plant: ``state``; a joint: its name) and the labels of its states.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ...core.cdr import (F64_ARRAY, JOINT_STATE, FloatEncoder, JointStateEncoder, float_block,
                         joint_state_block)
from ...core.errors import ConfigError
from ..settings import FIELDS


@dataclass(frozen=True)
class OutputSpec:
    """One output (see the module doc)."""

    topic: str
    msgtype: str
    labels: tuple           # per entry
    rows: np.ndarray        # (E,) the joint row of each entry
    fields: tuple           # per value array: None (empty) or (source 'x' | 'w' | 'c', cols (E,))


def _spec(topic, msgtype, labels, rows, *fields) -> OutputSpec:
    return OutputSpec(topic, msgtype, tuple(labels), np.asarray(rows, np.int64),
                      tuple(None if f is None else (f[0], np.asarray(f[1], np.int64))
                            for f in fields))


class OutputPlan:
    """The outputs of a source and their encoders (see the module doc)."""

    def __init__(self, specs, targets, frame_id: str):
        self.specs = tuple(specs)
        self.targets = tuple(targets)
        self.frame_id = frame_id
        self._block: dict = {}
        self._one: dict = {}

    def set_frame(self, frame_id: str) -> None:
        """header.frame_id of the JointStates from now on."""
        self.frame_id = frame_id
        self._block.clear()
        self._one.clear()

    @staticmethod
    def _values(spec: OutputSpec, field, sel, x, w, c) -> np.ndarray:
        src, cols = field
        arr = {"x": x, "w": w, "c": c}[src]
        v = arr[:, spec.rows[sel], cols[sel]]
        if src == "c" and not np.isfinite(v).all():
            v = np.where(np.isfinite(v), v, -1.0)
        return v

    def _encoder(self, cache: dict, i: int, sel: np.ndarray, one: bool):
        key = (i, sel.tobytes())
        enc = cache.get(key)
        if enc is None:
            spec = self.specs[i]
            labels = [spec.labels[e] for e in sel]
            if spec.msgtype == F64_ARRAY:
                enc = FloatEncoder(len(sel), labels) if one else float_block(len(sel), labels)
            else:
                sizes = tuple(0 if f is None else len(sel) for f in spec.fields)
                enc = (JointStateEncoder(labels, sizes, self.frame_id) if one else
                       joint_state_block(labels, sizes, self.frame_id))
            cache[key] = enc
        return enc

    def encode_block(self, i: int, t_ns: np.ndarray, x, w, c, ok) -> list:
        """Output ``i`` of K samples: ``[(rows of the K, payloads (k, L) uint8), ...]``, one
        item per run of samples with the same joints.  x (K, J, n), w (K, J, r), c (K, J,
        ncf) the runner's outputs, ok (K, J) which joints have one."""
        spec = self.specs[i]
        mask = ok[:, spec.rows]
        cuts = np.flatnonzero(np.any(mask[1:] != mask[:-1], axis=1)) + 1
        out = []
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(mask)]):
            sel = np.flatnonzero(mask[lo])
            if not sel.size:
                continue
            enc = self._encoder(self._block, i, sel, False)
            parts = [None if f is None else self._values(spec, f, sel, x[lo:hi], w[lo:hi], c[lo:hi])
                     for f in spec.fields]
            if spec.msgtype == F64_ARRAY:
                payloads = enc(parts[0])
            else:
                t = t_ns[lo:hi]
                none = np.zeros((hi - lo, 0))
                payloads = enc(t // 1_000_000_000, t % 1_000_000_000,
                               *(none if p is None else p for p in parts))
            out.append((np.arange(lo, hi), payloads))
        return out

    def encode_one(self, i: int, sec: int, nanosec: int, x, w, c, ok_row) -> bytes | None:
        """Output ``i`` of one sample (x (J, n), w (J, r), c (J, ncf), ok_row (J,)), or None
        when none of its joints has an output."""
        spec = self.specs[i]
        sel = np.flatnonzero(ok_row[spec.rows])
        if not sel.size:
            return None
        enc = self._encoder(self._one, i, sel, True)
        parts = [None if f is None else self._values(spec, f, sel, x[None], w[None], c[None])[0]
                 for f in spec.fields]
        if spec.msgtype == F64_ARRAY:
            return enc.encode(parts[0])
        return enc.encode(sec, nanosec, *parts)


# -- the plans ---------------------------------------------------------------------------
def unknown_input_names(obs) -> list[str]:
    """The names of an observer's unknown inputs ([] without one)."""
    if not obs.has_unknown_input:
        return []
    return list(getattr(obs, "unknown_input_names", None) or
                [f"zeta{j}" for j in range(obs.n_outputs)])


def estimated_joint_states(settings: Mapping[str, Any]):
    """(names, per JointState field the state indices or None) of the
    ``estimated_joint_states.*`` settings, or None when they name no joint."""
    names = settings["estimated_joint_states.joint_names"]
    if not names:
        return None
    idx = []
    for field in FIELDS:
        ix = settings[f"estimated_joint_states.{field}_states"]
        if not ix or all(i < 0 for i in ix):
            idx.append(None)
        elif any(i < 0 for i in ix):
            raise ConfigError(f"estimated_joint_states.{field}_states",
                              "give an index for every joint or for none (JointState fields "
                              "are all-or-nothing)")
        else:
            idx.append(ix)
    return names, idx


def _elements(prefixes, rows, names) -> tuple:
    """(labels, rows, cols) of every element ``names`` of every row, labelled prefix + name."""
    k = len(names)
    labels = [f"{p}{nm}" for p in prefixes for nm in names]
    return labels, np.repeat(rows, k), np.tile(np.arange(k), len(rows))


def _common(prefixes, rows, state_names, ui_names, conv_fields) -> list[OutputSpec]:
    """The labelled arrays and stamped JointStates of the estimate and the unknown input,
    and the convergence values."""
    out = []
    for what, names, src in (("state", state_names, "x"), ("unknown_input", ui_names, "w")):
        if not names:
            continue
        labels, r, cols = _elements(prefixes, rows, names)
        out.append(_spec(f"{what}_estimate", F64_ARRAY, labels, r, (src, cols)))
        out.append(_spec(f"{what}_estimate_stamped", JOINT_STATE, labels, r, (src, cols),
                         None, None))
    labels, r, cols = _elements(prefixes, rows, conv_fields)
    out.append(_spec("convergence", F64_ARRAY, labels, r, ("c", cols)))
    return out


def whole_plant_plan(runner) -> OutputPlan:
    """The outputs of one observer of the whole plant (see the module doc)."""
    obs, settings = runner.observer, runner.settings
    specs = _common([""], np.zeros(1, np.int64), list(obs.state_names),
                    unknown_input_names(obs), list(runner.convergence_fields))
    mapping = estimated_joint_states(settings)
    if mapping is not None:
        names, idx = mapping
        specs.append(_spec("estimated_joint_states", JOINT_STATE, names, np.zeros(len(names)),
                           *(None if ix is None else ("x", ix) for ix in idx)))
    return OutputPlan(specs, [("state", tuple(obs.state_names))], settings["output.frame_id"])


def per_joint_plan(runner) -> OutputPlan:
    """The outputs of one observer per joint (see the module doc)."""
    obs, settings, joints = runner.observer, runner.settings, list(runner.joints)
    roles = runner.roles
    first = roles[0]
    if any(r != first for r in roles[1:]):      # the same plant: the same roles
        raise ConfigError("joints", "the joints' states play different roles")
    J = len(joints)
    rows = np.arange(J)
    eff_from, eff = first.effort
    fields = [("x", np.full(J, first.position)),
              None if first.velocity < 0 else ("x", np.full(J, first.velocity)),
              None if eff_from == "none" else ("w" if eff_from == "unknown_input" else "x",
                                               np.full(J, eff))]
    specs = [_spec("estimated_joint_states", JOINT_STATE, joints, rows, *fields)]
    specs += _common([f"{j}/" for j in joints], rows, list(obs.state_names),
                     unknown_input_names(obs)[:runner._mem.r], list(runner.convergence_fields))
    targets = [(j, tuple(f"{j}/{s}" for s in obs.state_names)) for j in joints]
    return OutputPlan(specs, targets, settings["output.frame_id"])
