"""Architecture and documentation checks that keep the layering and the README honest."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from fto_ros.observers import REGISTRY
from fto_ros.runner.settings import SETTINGS

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "fto_ros"

#: layer -> top-level modules it must not import (DESIGN.md, "Layers")
FORBIDDEN = {
    "core": {"rclpy", "rosbags", "mcap", "matplotlib", "fto_ros.observers", "fto_ros.runner",
             "fto_ros.nodes", "fto_ros.replay", "fto_ros.bag", "fto_ros.cli", "fto_ros.models",
             "fto_ros.plant"},
    "models": {"rclpy", "rosbags", "mcap", "fto_ros.observers", "fto_ros.runner", "fto_ros.nodes",
               "fto_ros.replay", "fto_ros.bag", "fto_ros.cli"},
    "observers": {"rclpy", "rosbags", "mcap", "fto_ros.runner", "fto_ros.nodes", "fto_ros.replay",
                  "fto_ros.bag", "fto_ros.cli", "fto_ros.plant"},
    # the plant block and the derivations: above observers/ (they build their parameters),
    # below runner/ (which expands the plant block before it builds an observer)
    "plant": {"rclpy", "rosbags", "mcap", "matplotlib", "fto_ros.runner", "fto_ros.nodes",
              "fto_ros.replay", "fto_ros.bag", "fto_ros.cli", "fto_ros.models"},
    "runner": {"rclpy", "rosbags", "mcap", "fto_ros.nodes", "fto_ros.replay", "fto_ros.bag", "fto_ros.cli"},
    "bag": {"rclpy", "fto_ros.nodes", "fto_ros.replay", "fto_ros.cli"},
    "replay": {"rclpy", "fto_ros.nodes"},
    # sweeps replay offline, in worker processes or on a cluster: no DDS anywhere
    "sweep": {"rclpy", "fto_ros.nodes"},
}


def imports_of(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    mod = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    pkg = mod.rsplit(".", 1)[0] if path.name != "__init__.py" else mod
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[:len(base) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module
            out.add(name)
            out.update(f"{name}.{a.name}" for a in node.names)
    return out


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layers_import_only_downwards(layer):
    bad = []
    for path in sorted((PKG / layer).glob("*.py")):
        for name in imports_of(path):
            if any(name == f or name.startswith(f + ".") for f in FORBIDDEN[layer]):
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not bad, "\n".join(bad)


def test_lower_layers_load_without_rclpy():
    """Import core, models, observers, runner with rclpy made unimportable."""
    code = ("import sys; sys.modules['rclpy'] = None\n"
            "import fto_ros.core.discretize, fto_ros.models.dc_motor, fto_ros.observers, fto_ros.plant\n"
            "import fto_ros.runner\n"
            "from fto_ros.runner import Runner\n"
            "from fto_ros.runner.params_file import load_params_files\n"
            "from fto_ros.runner.plant_files import params_files\n"
            "Runner(load_params_files(params_files('config/dc_motor_single_delay.yaml')))\n")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


def test_readme_documents_every_parameter():
    readme = (ROOT / "README.md").read_text()
    from fto_ros.cli.simulate_plant import SIM_PARAMS
    from fto_ros.plant import PLANT_PARAMS
    names = [p.name for p in SETTINGS]
    names += [f"{t}.{p.name}" for t, cls in REGISTRY.items() for p in cls.PARAMS]
    names += [f"plant.{p.name}" for p in PLANT_PARAMS] + [f"simulation.{p.name}" for p in SIM_PARAMS]
    missing = [n for n in names if f"`{n}`" not in readme]
    assert not missing, f"README.md lacks (regenerate with python -m fto_ros.cli.paramdoc): {missing}"


def test_every_config_builds():
    """Every tuning file, with its system's plant file when it needs one (plant files are
    no configs of their own: runner/plant_files.py)."""
    from fto_ros.runner import Runner
    from fto_ros.runner.params_file import load_params_files
    from fto_ros.runner.plant_files import is_plant_file, params_files
    for path in sorted((ROOT / "config").glob("*.yaml")):
        if not is_plant_file(path):
            Runner(load_params_files(params_files(path)))
