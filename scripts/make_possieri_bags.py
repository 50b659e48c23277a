"""Write the bags of Possieri, Vidano & Novara 2020's example (22), the paper's three cases.

    PYTHONPATH=. python scripts/make_possieri_bags.py [--out-dir bags] [--duration 10] [--rate 1000]

bags/possieri_example (noiseless), bags/possieri_example_white_noise (band-limited white
noise, power 1e-4, sample time 1e-3, seed 0) and bags/possieri_example_sinusoid
(0.01 sin 48 t): 10 s at 1 kHz, u = 0.4 sin 3t + 0.5 sin 2t + 0.2 sin 5t applied
continuously to the plant (sampled in the bag), x(0) = (1, 2).  Topics
/possieri_example/measured_output [y], /possieri_example/input [u] (no derivatives:
the observer estimates them, Remark 5), /possieri_example/true_state [x1, x2], /clock.
The settings are stored in metadata.yaml custom_data under fto_ros.simulation.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fto_ros import __version__  # noqa: E402
from fto_ros.bag import BagWriter  # noqa: E402
from fto_ros.models import possieri_example as pe  # noqa: E402
from fto_ros.models.simulate import to_ns, uniform_grid  # noqa: E402

CASES = {
    "possieri_example": ("none", "noiseless output (Fig. 1(b))"),
    "possieri_example_white_noise": ("white_noise", "band-limited white noise, power 1e-4, "
                                     "sample time 1e-3 (variance 0.1, held 1 ms), seed 0 (Fig. 1(c))"),
    "possieri_example_sinusoid": ("sinusoid", "d(t) = 0.01 sin(48 t) (Fig. 1(d), Fig. 2)"),
}


def write(out: Path, disturbance: str, what: str, duration: float, rate: float, seed: int) -> None:
    t = uniform_grid(duration, rate)
    sim = pe.simulate_example(t, disturbance, seed=seed)
    sysname = pe.SPEC.name
    topics = {k: f"/{sysname}/{k}" for k in ("input", "measured_output", "true_state")}
    settings = {
        "fto_ros_version": __version__, "model": sysname, "description": pe.SPEC.description,
        "state_names": list(pe.STATE_NAMES), "input_names": ["u"], "output_names": ["y"],
        "x0": list(pe.DEFAULT_X0), "t0": 0.0, "duration": duration, "base_rate": rate,
        "input_profile": pe.SPEC.input_description,
        "input_hold": "none: the plant sees the continuous u(t); the bag holds its samples",
        "measurement_disturbance": {"type": disturbance, "description": what, "seed": seed},
        "integrator": {"method": "DOP853", "rtol": 1e-12, "atol": 1e-13},
        "topics": {**topics, "clock": "/clock"},
        "generator": "scripts/make_possieri_bags.py",
        "log_time": "sample time, round(t * 1e9) ns, t = 0 at the start",
    }
    with BagWriter(out, overwrite=True, custom_data={"fto_ros.simulation": json.dumps(settings, sort_keys=True)}) as bag:
        for i, ti in enumerate(t):
            ns = to_ns(ti)
            bag.clock(ns)
            bag.float_array(topics["input"], ns, sim["u"][i])
            bag.float_array(topics["true_state"], ns, sim["x"][i])
            bag.float_array(topics["measured_output"], ns, sim["y"][i])
    print(f"wrote {out} ({len(t)} samples, {what})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out-dir", default="bags")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    for name, (dist, what) in CASES.items():
        write(Path(args.out_dir) / name, dist, what, args.duration, args.rate, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
