"""The launch files in launch/, checked as far as a machine without ROS's `launch` package
can (it is not on PyPI, so the venv cannot import it): each file compiles, defines
generate_launch_description and imports only the launch and launch_ros APIs; the arguments
it declares are exactly the ones docs/ros_interface.md documents, with the same defaults
and choices; the example files include observer.launch.py with a params file that exists,
and reach every committed config; the executables they start are console scripts; a pip
install puts them under share/fto_ros/launch (the colcon install is checked in
test_colcon_build.py). test_ros2_cli.py runs each of them with the real `ros2 launch`.
"""
from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / "launch"
CONFIG = ROOT / "config"
INTERFACE = ROOT / "docs" / "ros_interface.md"
FILES = sorted(LAUNCH.glob("*.launch.py"))
MAIN = LAUNCH / "observer.launch.py"
EXAMPLES = [f for f in FILES if f != MAIN]
#: the external-torque node's (no observer, no params-file choice): test/system/test_arm_node_live.py
TORQUE = LAUNCH / "arm7_external_torque.launch.py"
EXAMPLES = [f for f in EXAMPLES if f != TORQUE]


# ----------------------------------------------------------------------------- helpers
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _name(func: ast.expr) -> str:
    return func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and _name(n.func) == name]


def _constants(tree: ast.Module) -> dict:
    """Module-level NAME = <literal> assignments."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                and isinstance(node.targets[0], ast.Name):
            try:
                out[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass
    return out


def _value(node: ast.expr, constants: dict):
    if isinstance(node, ast.Name) and node.id in constants:
        return constants[node.id]
    return ast.literal_eval(node)


def _keyword(call: ast.Call, name: str) -> ast.expr | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def declared(path: Path) -> dict[str, tuple[str | None, list[str] | None]]:
    """{argument: (default or None, choices or None)} of every DeclareLaunchArgument."""
    tree = _tree(path)
    consts = _constants(tree)
    out = {}
    for call in _calls(tree, "DeclareLaunchArgument"):
        name = _value(call.args[0], consts)
        default, choices = _keyword(call, "default_value"), _keyword(call, "choices")
        assert name not in out, f"{path.name} declares {name!r} twice"
        out[name] = (None if default is None else _value(default, consts),
                     None if choices is None else list(_value(choices, consts)))
    return out


def _strings(node: ast.AST) -> list[str]:
    return [n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def documented_arguments() -> dict[str, str | None]:
    """The argument table of observer.launch.py in docs/ros_interface.md: {name: default}
    (None: required; '' for '(empty)')."""
    text = INTERFACE.read_text()
    section = text[text.index("`observer.launch.py` starts one observer"):]
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+) \|", section.split("\n\n")[1], flags=re.M)
    assert rows, "docs/ros_interface.md lost the observer.launch.py argument table"
    out = {}
    for name, default in rows:
        default = default.strip()
        out[name] = None if default == "(required)" else "" if default == "(empty)" \
            else default.strip("`")
    return out


def documented_examples() -> dict[str, list[str]]:
    """{launch file: observer choices, the default first} from docs/ros_interface.md."""
    rows = re.findall(r"^\| `(\w+\.launch\.py)` \| (.+) \|$", INTERFACE.read_text(), flags=re.M)
    assert rows, "docs/ros_interface.md lost the table of example launch files"
    return {name: re.findall(r"`(\w+)`", cell) for name, cell in rows}


def config_prefix(path: Path) -> str:
    """The '<system>_' of the params file an example builds: [share, '/config/<system>_',
    LaunchConfiguration('observer'), '.yaml'] (substitutions concatenated)."""
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.List) and any(
                isinstance(e, ast.Call) and _name(e.func) == "LaunchConfiguration"
                and _strings(e) == ["observer"] for e in node.elts):
            assert len(node.elts) == 4, f"{path.name}: [share, '/config/<system>_', observer, '.yaml']"
            share, middle, _, last = node.elts
            assert isinstance(share, ast.Name) and share.id == "share", path.name
            assert isinstance(middle, ast.Constant) and middle.value.startswith("/config/")
            assert isinstance(last, ast.Constant) and last.value == ".yaml", \
                f"{path.name}: the params file must end in .yaml"
            return middle.value[len("/config/"):]
    raise AssertionError(f"{path.name} builds no config/<system>_<observer>.yaml path")


def console_scripts() -> set[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for call in _calls(tree, "setup"):
        entry = _keyword(call, "entry_points")
        scripts = ast.literal_eval(entry)["console_scripts"]
        return {s.split("=")[0].strip() for s in scripts}
    raise AssertionError("setup.py has no setup() call")


# ------------------------------------------------------------------------------ tests
def test_there_is_an_observer_launch_file_and_one_per_example():
    assert MAIN in FILES and EXAMPLES


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_compiles_and_defines_generate_launch_description(path):
    code = compile(path.read_text(), str(path), "exec")
    assert code is not None
    funcs = [n for n in _tree(path).body if isinstance(n, ast.FunctionDef)
             and n.name == "generate_launch_description"]
    assert len(funcs) == 1, f"{path.name}: no module-level generate_launch_description()"
    args = funcs[0].args
    assert not args.args and not args.posonlyargs and not args.kwonlyargs, \
        "ros2 launch calls generate_launch_description() without arguments"


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_imports_only_the_launch_apis(path):
    """Public launch / launch_ros APIs only, and of fto_ros only its plant-file rule
    (fto_ros.runner.plant_files, ROS-free), imported at launch time: nothing that a ROS
    install with the package would not have."""
    modules = set()
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Import):
            modules.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            modules.add(node.module)
    top = {m.split(".")[0] for m in modules}
    assert top <= {"launch", "launch_ros", "fto_ros"}, f"{path.name} imports {sorted(modules)}"
    assert {m for m in modules if m.startswith("fto_ros")} <= {"fto_ros.runner.plant_files"}


def test_the_plant_file_rule_is_the_replay_tools_one():
    """observer.launch.py hands params_files() the tuning file: [plant, tuning] or [tuning]."""
    from fto_ros.runner.plant_files import params_files
    assert params_files(CONFIG / "dc_motor_single_delay.yaml") == [
        CONFIG / "dc_motor_plant.yaml", CONFIG / "dc_motor_single_delay.yaml"]
    assert params_files(CONFIG / "fld_example1_hosm.yaml") == [CONFIG / "fld_example1_hosm.yaml"]
    assert "params_files(LaunchConfiguration('params_file').perform(context))" in MAIN.read_text()


def test_observer_launch_declares_the_documented_arguments():
    got = {name: default for name, (default, _) in declared(MAIN).items()}
    assert got == documented_arguments()


def test_observer_launch_boolean_arguments_accept_only_true_and_false():
    for name, (default, choices) in declared(MAIN).items():
        if default in ("true", "false"):
            assert sorted(choices or []) == ["false", "true"], name


def test_observer_launch_starts_the_plain_node_unless_managed():
    tree = _tree(MAIN)
    consts = _constants(tree)
    plain, managed = _calls(tree, "Node"), _calls(tree, "LifecycleNode")
    assert len(plain) == 1 and len(managed) == 1
    for call, executable, condition in ((plain[0], "observer_node", "UnlessCondition"),
                                        (managed[0], "managed_observer_node", "IfCondition")):
        assert _value(_keyword(call, "package"), consts) == "fto_ros"
        assert _value(_keyword(call, "executable"), consts) == executable
        cond = _keyword(call, "condition")
        assert isinstance(cond, ast.Call) and _name(cond.func) == condition, executable
        for kw in ("name", "namespace", "parameters"):
            assert _keyword(call, kw) is not None, f"{executable}: no {kw}="
        params = _keyword(call, "parameters")
        keys = {k.value for d in ast.walk(params) if isinstance(d, ast.Dict) for k in d.keys}
        assert "use_sim_time" in keys, executable
    managed_keys = {k.value for d in ast.walk(_keyword(managed[0], "parameters"))
                    if isinstance(d, ast.Dict) for k in d.keys}
    assert "autostart" in managed_keys


def test_every_example_launch_file_is_documented():
    assert sorted(p.name for p in EXAMPLES) == sorted(documented_examples())


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_declares_the_documented_observer_choices(path):
    doc = documented_examples()[path.name]
    assert declared(path) == {"observer": (doc[0], doc)}


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_reaches_only_existing_configs(path):
    prefix = config_prefix(path)
    assert prefix == path.name[:-len("launch.py")].rstrip(".") + "_"
    _, choices = declared(path)["observer"]
    missing = [c for c in choices if not (CONFIG / f"{prefix}{c}.yaml").is_file()]
    assert not missing, f"{path.name}: no config/{prefix}<observer>.yaml for {missing}"
    # and nothing else: the file's other strings name no params file
    other = [s for s in _strings(_tree(path)) if re.fullmatch(r"[\w./-]+\.yaml", s)]
    assert not other, f"{path.name} names params files directly: {other}"


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_includes_observer_launch_with_its_params_file(path):
    includes = _calls(_tree(path), "IncludeLaunchDescription")
    assert len(includes) == 1, f"{path.name} must include observer.launch.py once"
    assert "observer.launch.py" in _strings(includes[0].args[0])
    args = _keyword(includes[0], "launch_arguments")
    keys = [k.value for d in ast.walk(args) if isinstance(d, ast.Dict) for k in d.keys]
    assert keys == ["params_file"], f"{path.name} passes {keys}"


def test_every_committed_config_has_an_example_launch_file():
    """A config that names its observer type runs on its own; one of the example launch
    files must be able to start it."""
    reachable = set()
    for path in EXAMPLES:
        prefix = config_prefix(path)
        reachable.update(f"{prefix}{c}.yaml" for c in declared(path)["observer"][1])
    standalone = []
    for cfg in sorted(CONFIG.glob("*.yaml")):
        doc = yaml.safe_load(cfg.read_text()) or {}
        blocks = [b.get("ros__parameters", {}) for b in doc.values() if isinstance(b, dict)]
        if any(isinstance(b.get("observer"), dict) and "type" in b["observer"] for b in blocks):
            standalone.append(cfg.name)
    missing = sorted(set(standalone) - reachable)
    assert standalone and not missing, f"no example launch file starts {missing}"


def _executables():
    names = set()
    for path in FILES:
        for call in _calls(_tree(path), "Node") + _calls(_tree(path), "LifecycleNode"):
            names.add(ast.literal_eval(_keyword(call, "executable")))
    return sorted(names)


@pytest.mark.parametrize("executable", _executables())
def test_launched_executables_are_console_scripts(executable):
    assert executable in console_scripts()


@pytest.mark.slow
def test_pip_install_puts_launch_and_config_files_under_share(tmp_path):
    """Build the wheel pip installs from (data files included) and look inside."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("setup.py", "setup.cfg", "requirements.txt", "package.xml", "MANIFEST.in"):
        shutil.copy(ROOT / name, src / name)
    for name in ("resource", "config", "launch", "fto_ros"):
        shutil.copytree(ROOT / name, src / name,
                        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    result = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q",
                             "-w", str(tmp_path / "dist"), str(src)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    wheel, = (tmp_path / "dist").glob("fto_ros-*.whl")
    data = {n.split(".data/data/", 1)[1] for n in zipfile.ZipFile(wheel).namelist()
            if ".data/data/" in n}
    want = {f"share/fto_ros/launch/{p.name}" for p in FILES}
    want |= {f"share/fto_ros/config/{p.name}" for p in CONFIG.glob("*.yaml")}
    want |= {"share/fto_ros/package.xml", "share/ament_index/resource_index/packages/fto_ros"}
    assert want <= data, f"not installed by pip: {sorted(want - data)}"
