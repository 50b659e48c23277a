"""Shared pieces of the fault-injection suite (test_faults_*.py): every committed config
with a clean stream from its bag, the junk families, and the operation counter whose
totals the suite prints.  Seeded: the same seed gives the same operations."""
from __future__ import annotations

import copy
import math
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from fto_ros.bag import BagReader
from fto_ros.cli.report import plan, plan_examples
from fto_ros.replay.topics import resolve_topic
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parents[2]
#: seconds of each bag kept as the clean stream
STREAM_SECONDS = 2.0

#: operations tried, per family, over the whole session (printed at the end)
COUNTS: Counter[str] = Counter()


@dataclass
class Config:
    name: str                     # the tuning file's stem
    params: list[Path]            # the params files, merged in order
    bag: Path


def _params(pair) -> list[Path]:
    files = getattr(pair, "params", None)
    return list(files) if files else [pair.config]


@lru_cache(maxsize=None)
def committed_configs() -> tuple[Config, ...]:
    """Every committed config of one observer (not per joint) with the bag the main job
    replays it on (its first one).  The per-joint configs (``joints: [...]``, the arm's)
    take a JointState stream these suites do not build: their junk is injected per joint by
    test/unit/replay/test_replay_joints.py, test/system/test_node_joints_live.py and test_faults_live.py."""
    pairs, _ = plan(ROOT / "bags", ROOT / "config")
    pairs += plan_examples(ROOT / "bags", ROOT / "config")
    out: dict[str, Config] = {}
    for p in pairs:
        name = p.config.stem
        if name not in out and p.bag.exists() and not per_joint(_params(p)):
            out[name] = Config(name, _params(p), p.bag)
    return tuple(out[k] for k in sorted(out))


def per_joint(params: list[Path]) -> bool:
    """Whether these params files run one observer per joint."""
    return bool(load_params_files([str(f) for f in params]).get("joints"))


@dataclass
class Stream:
    """A clean stream: events (t, kind, values) with kind 'u' (input) or 'y' (measurement),
    inputs first at equal stamps, times from 0."""

    events: list
    n_in: int
    n_out: int

    def shifted(self, offset: float) -> list:
        return [(t + offset, k, v) for t, k, v in self.events]


@lru_cache(maxsize=None)
def stream(bag: Path, meas: str, inp: str | None, seconds: float = STREAM_SECONDS,
           truth: str | None = None) -> Stream:
    ev = []
    with BagReader(bag) as b:
        topics = [meas] + ([inp] if inp else []) + ([truth] if truth in b.topics else [])
        t0 = None
        for topic, t_ns, msg in b.messages(topics):
            t0 = t_ns if t0 is None else t0
            t = (t_ns - t0) / 1e9
            if t > seconds:
                break
            kind = "u" if topic == inp else ("x" if topic == truth else "y")
            ev.append((t, kind, [float(v) for v in msg.data]))
    ev.sort(key=lambda e: (e[0], "uyx".index(e[1])))
    n_out = len(next(v for _, k, v in ev if k == "y"))
    n_in = len(next((v for _, k, v in ev if k == "u"), []))
    return Stream(ev, n_in, n_out)


_TEMPLATES: dict = {}


def runner_for(cfg: Config, **changes) -> Runner:
    """A fresh Runner for the config (built once, then deep-copied: some designs are slow)."""
    key = (cfg.name, repr(sorted(changes.items())))
    if key not in _TEMPLATES:
        flat = load_params_files(cfg.params)
        flat.update(changes)
        _TEMPLATES[key] = Runner(flat)
    return copy.deepcopy(_TEMPLATES[key])


def stream_for(cfg: Config, seconds: float = STREAM_SECONDS, truth: bool = False) -> Stream:
    """The config's clean stream; with ``truth`` the ground truth too (events of kind 'x')."""
    r = runner_for(cfg)
    meas = resolve_topic(r.settings["topics.measured_output"], "/observer_node")
    inp = resolve_topic(r.settings["topics.input"], "/observer_node") if r.observer.n_inputs else None
    x = resolve_topic(r.settings["topics.true_state"], "/observer_node") if truth else None
    return stream(cfg.bag, meas, inp, seconds, x)


def feed(r: Runner, events, outs: list | None = None) -> None:
    """Feed clean events; every result is checked (finite when an Output)."""
    for t, kind, v in events:
        if kind == "u":
            r.set_input(t, v)
        else:
            res = r.process(t, v)
            check_result(res)
            if outs is not None:
                outs.append(res)


def check_result(res) -> None:
    """An Output with only finite values, or a reason string."""
    if isinstance(res, str):
        assert res, "empty reason"
        return
    assert np.all(np.isfinite(res.estimate)), res
    assert np.all(np.isfinite(res.convergence[[0, 1, 2, 4]])), res
    assert res.unknown_input is None or np.all(np.isfinite(res.unknown_input)), res
    assert math.isfinite(res.t)


# -- junk ---------------------------------------------------------------------------------------
def junk_values(n: int, rng: np.random.Generator):
    """A value a measurement or input channel of length n may be sent that the runner must
    refuse: (family, value)."""
    nan, inf = float("nan"), float("inf")
    choices = [
        ("non_finite", [nan] * n), ("non_finite", [inf] * max(n, 1)),
        ("non_finite", [-inf] + [0.0] * (n - 1) if n else [-inf]),
        ("absurd", [1e300] * n if n else [1e300]), ("absurd", [-1e300] * max(n, 1)),
        ("wrong_length", [0.0] * (n + 1)), ("wrong_length", [0.0] * (n + 7)),
        ("wrong_type", "abc"), ("wrong_type", None), ("wrong_type", {"a": 1}),
        ("wrong_type", [[0.0]] * n if n else [[0.0]]), ("wrong_type", [1j] * max(n, 1)),
        ("wrong_type", 3.0), ("wrong_type", b"\x00\x01"),
    ]
    if n == 0:
        choices = [c for c in choices if not (isinstance(c[1], list) and len(c[1]) == 0)]
    return choices[rng.integers(len(choices))]


def junk_stamps(t_last: float, rng: np.random.Generator):
    """A stamp the runner must not act on (family, t): rejected, or held and then dropped
    when the clean stream goes on."""
    choices = [
        ("stamp_repeated", t_last), ("stamp_back_small", t_last - 1e-4),
        ("stamp_back_big", t_last - 1.0), ("stamp_negative", -1.0 - rng.random()),
        ("stamp_future", t_last + 1e6), ("stamp_future", 1e300), ("stamp_non_finite", float("nan")),
        ("stamp_non_finite", float("inf")), ("stamp_int32", 2.0 ** 31 + rng.random()),
        ("stamp_too_close", t_last + 1e-8),
    ]
    return choices[rng.integers(len(choices))]
