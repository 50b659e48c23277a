"""A committed (bag, config) pair's sensitivity to its data moved by one unit roundoff: the
measured conditioning the golden master (test_kernel_reference.py) takes its bars from.

Another CPU runs the same replay with other last bits: OpenBLAS picks its kernels by CPU
(Haswell, Zen, SkylakeX, ...), which order the sums of a product differently, so every
matrix product, solve and exponential the design and the steps make comes out a few units
in the last place apart.  A backward-stable computation returns the exact result for data
moved by such amounts, so how far those last bits carry is the pair's own conditioning: the
largest change of its outputs when its data moves by one unit roundoff (Kenney & Laub's
small-sample statistical condition estimate, with the run's thousands of samples as the
sample).  ``perturbed_replay`` measures it on the spot: every number of the pair's params
files (plant constants, poles, gains, T, noise levels ...) times (1 +- eps) and every
sample the replay hands the runner (measured outputs and inputs) times (1 +- eps), the signs
drawn from ``seed``; the calls and statuses must stay those of the plain replay (an eps
that flips a decision would make the pair's reference depend on one machine's last bits).
"""
from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np

import reference_runs as RR
from fto_ros.runner import runner as R

EPS = float(np.finfo(float).eps)
#: a decimal number with a point or an exponent (an integer stays: counts, orders, flags)
_FLOAT = re.compile(r"(?<![\w.])[-+]?(?:\d+\.\d*|\.\d+|\d+(?=[eE]))(?:[eE][-+]?\d+)?(?![\w.])")


def _moved(value: float, rng: np.random.Generator) -> float:
    return float(value * (1.0 + EPS * float(rng.choice((-1.0, 1.0)))))


def perturbed_params(files: list[Path], folder: Path, rng: np.random.Generator) -> list[Path]:
    """Copies of ``files`` in ``folder`` with every decimal number moved by one unit
    roundoff (in comments too: harmless); the text stays what the params reader reads."""
    out = []
    for i, f in enumerate(files):
        path = folder / f"{i}_{f.name}"
        path.write_text(_FLOAT.sub(lambda m: repr(_moved(float(m.group()), rng)), f.read_text()))
        out.append(path)
    return out


def perturbed_replay(pair: dict, seed: int):
    """``RR.log_replay`` of ``pair`` with its params files and samples moved by one unit
    roundoff (see the module docstring): (calls, runner)."""
    rng = np.random.default_rng(seed)
    plain = R.Runner.process_block

    def process_block(self, kind, t, values, refused=None):
        values = np.array(values, dtype=float)
        values *= 1.0 + EPS * rng.choice((-1.0, 1.0), size=values.shape)
        return plain(self, kind, t, values, refused)

    with tempfile.TemporaryDirectory() as folder:
        params = perturbed_params([RR.ROOT / f for f in pair["params"]], Path(folder), rng)
        R.Runner.process_block = process_block
        try:
            return RR.log_replay(RR.ROOT / "bags" / pair["bag"], params)
        finally:
            R.Runner.process_block = plain
