"""Architecture and documentation checks that keep the layering, the README and docs/ honest."""
from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fto_ros.observers import REGISTRY
from fto_ros.runner.settings import SETTINGS

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "fto_ros"

#: layer -> top-level modules it must not import (docs/architecture.md, "Layers")
FORBIDDEN = {
    "core": {"rclpy", "rosbags", "mcap", "matplotlib", "fto_ros.observers", "fto_ros.runner",
             "fto_ros.nodes", "fto_ros.replay", "fto_ros.bag", "fto_ros.cli", "fto_ros.models",
             "fto_ros.plant", "fto_ros.arm"},
    # the arm room: rigid bodies from their URDF (compiled dynamics, Pinocchio the reference),
    # the window numerics and the in-kernel detection: above core/, below models/ (the arm
    # simulator) and observers/
    "arm": {"rclpy", "rosbags", "mcap", "matplotlib", "fto_ros.models", "fto_ros.observers",
              "fto_ros.plant", "fto_ros.runner", "fto_ros.nodes", "fto_ros.replay", "fto_ros.bag",
              "fto_ros.cli", "fto_ros.sweep"},
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
    # the command-line tools (cli/) sit on top: what replay/ and sweep/ share with them
    # (argument types, one-line errors) is core/command_line.py
    "replay": {"rclpy", "fto_ros.nodes", "fto_ros.cli"},
    # sweeps replay offline, in worker processes or on a cluster: no DDS anywhere
    "sweep": {"rclpy", "fto_ros.nodes", "fto_ros.cli"},
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


def test_every_exception_of_the_package_is_an_fto_ros_error():
    """One error base: every exception class defined in fto_ros/ derives from FtoRosError
    (a caller catches one type); warnings are notes, not errors."""
    import importlib
    import inspect
    from fto_ros.core.errors import FtoRosError
    found = []
    for path in sorted(PKG.rglob("*.py")):
        tree = ast.parse(path.read_text())
        classes = [n.name for n in tree.body if isinstance(n, ast.ClassDef)]
        if not classes or "rclpy" in str(imports_of(path)):
            continue
        mod = importlib.import_module(".".join(path.relative_to(ROOT).with_suffix("").parts))
        for name in classes:
            cls = getattr(mod, name)
            if inspect.isclass(cls) and issubclass(cls, BaseException) \
                    and not issubclass(cls, Warning):
                found.append(cls)
                assert issubclass(cls, FtoRosError), f"{path.name}: {name} is not an FtoRosError"
    assert len(found) >= 8, [c.__name__ for c in found]


def test_no_parameter_name_is_the_prefix_of_another():
    """`ros2 param dump` nests dotted names: a parameter `a` beside `a.b` breaks it (a list
    cannot hold a key), so no declared name may be a dotted prefix of another."""
    names = sorted(set(parameter_names()))
    assert len(names) > 50
    clashes = [(a, b) for a in names for b in names if b.startswith(a + ".")]
    assert not clashes, clashes


def test_lower_layers_load_without_rclpy():
    """Import core, models, observers, runner with rclpy made unimportable."""
    code = ("import sys; sys.modules['rclpy'] = None\n"
            "import fto_ros.core.discretize, fto_ros.models.dc_motor, fto_ros.observers, fto_ros.plant\n"
            "import fto_ros.arm.detect, fto_ros.arm.collision, fto_ros.models.arm\n"
            "import fto_ros.runner\n"
            "from fto_ros.runner import Runner\n"
            "from fto_ros.runner.params_file import load_params_files\n"
            "from fto_ros.runner.plant_files import params_files\n"
            "Runner(load_params_files(params_files('config/dc_motor_single_delay.yaml')))\n")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


def test_every_config_builds():
    """Every tuning file, with its system's plant file when it needs one (plant files are
    no configs of their own: runner/plant_files.py)."""
    from fto_ros.runner import Runner
    from fto_ros.runner.params_file import load_params_files
    from fto_ros.runner.plant_files import is_plant_file, params_files
    for path in sorted((ROOT / "config").glob("*.yaml")):
        if not is_plant_file(path):
            Runner(load_params_files(params_files(path)))



# ---------------------------------------------------------------- documentation
DOCS = ROOT / "docs"
INTERFACE = DOCS / "ros_interface.md"
REGENERATE = "regenerate with: python -m fto_ros.cli.paramdoc --write docs/ros_interface.md"


def parameter_names() -> list[str]:
    from fto_ros.cli.simulate_plant import SIM_PARAMS
    from fto_ros.plant import PLANT_PARAMS
    names = [p.name for p in SETTINGS]
    names += [f"{t}.{p.name}" for t, cls in REGISTRY.items() for p in cls.PARAMS]
    names += [f"plant.{p.name}" for p in PLANT_PARAMS] + [f"simulation.{p.name}" for p in SIM_PARAMS]
    return names


def test_ros_interface_documents_every_parameter():
    page = INTERFACE.read_text()
    missing = [n for n in parameter_names() if f"`{n}`" not in page]
    assert not missing, f"docs/ros_interface.md lacks {missing} ({REGENERATE})"


def test_ros_interface_parameter_tables_are_the_generators_output():
    """The tables between the page's markers are exactly what paramdoc prints, so a changed
    description, default or range fails too, and regenerating fixes it."""
    from fto_ros.cli import paramdoc
    printed = subprocess.run([sys.executable, "-m", "fto_ros.cli.paramdoc"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
    assert printed == paramdoc.generated()
    block = paramdoc.generated_block(INTERFACE.read_text())
    assert block is not None, f"docs/ros_interface.md lost its paramdoc marker lines ({REGENERATE})"
    assert block == printed, f"docs/ros_interface.md's parameter tables are stale ({REGENERATE})"


def test_paramdoc_write_fills_the_marked_block(tmp_path):
    from fto_ros.cli import paramdoc
    page = tmp_path / "page.md"
    page.write_text(f"# title\n\n{paramdoc.BEGIN}\nold tables\n{paramdoc.END}\n\nafter\n")
    assert paramdoc.main(["--write", str(page)]) == 0
    text = page.read_text()
    assert text.startswith("# title\n\n") and text.endswith(f"{paramdoc.END}\n\nafter\n")
    assert paramdoc.generated_block(text) == paramdoc.generated()
    page.write_text("no markers\n")
    assert paramdoc.main(["--write", str(page)]) == 1
    assert page.read_text() == "no markers\n"


def test_every_observer_has_a_page_linked_from_the_readme():
    readme = (ROOT / "README.md").read_text()
    missing = [t for t in REGISTRY if not (DOCS / f"{t}.md").is_file()]
    unlinked = [t for t in REGISTRY if f"](docs/{t}.md)" not in readme]
    assert not missing and not unlinked, f"no docs/<type>.md: {missing}; not linked: {unlinked}"


def _tracked_text_files():
    """Every file of the repository (as git tracks it, plus untracked files it does not
    ignore) that reads as UTF-8 text."""
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                         cwd=ROOT, capture_output=True, check=True).stdout
    for name in out.decode().split("\0"):
        path = ROOT / name
        if not name or not path.is_file():
            continue
        try:
            yield path, path.read_text()
        except UnicodeDecodeError:
            continue


#: files that live outside the repository (spelt in pieces, so this test does not cite them)
OUTSIDE = ("DESIGN" + ".md", "/work/" + "shared", "reference/" + "differentiators.md",
           "reference/" + "ros_conventions.md")


def test_nothing_cites_a_file_outside_the_repository():
    """The architecture is documented in docs/architecture.md; a reader of the repository
    cannot open a design file or a note that lives elsewhere."""
    citing = [f"{p.relative_to(ROOT)}: {o}" for p, text in _tracked_text_files()
              for o in OUTSIDE if o in text]
    assert not citing, f"cite docs/ (architecture.md, the observer pages) instead: {citing}"


#: a test file cited by its path (test/...py) or by its name (test_...py)
_TEST_PATH = re.compile(r"(?<![\w./-])test/[\w/]+\.py\b")
_TEST_NAME = re.compile(r"(?<![\w./-])(test_\w+\.py)\b")


def test_cited_test_files_exist():
    """A test file cited anywhere in the repository (docs, README, the package's comments,
    benchmarks, scripts, the tests themselves), by its path or by its name, exists: when the
    suite's layout changes (test/unit/<room>/, test/system/, test/support/), no sentence
    sends a reader to a file that moved."""
    names = {p.name for p in (ROOT / "test").rglob("*.py")}
    stale = []
    for path, text in _tracked_text_files():
        where = path.relative_to(ROOT)
        stale += [f"{where}: {m}" for m in _TEST_PATH.findall(text) if not (ROOT / m).is_file()]
        stale += [f"{where}: {m}" for m in _TEST_NAME.findall(text) if m not in names]
    assert not stale, f"cited test files that do not exist: {sorted(set(stale))}"


#: test/unit/<room>/: a room per subpackage of fto_ros (arm: the rigid-body package's name
#: from issue 27 on)
ROOMS = {p.parent.name for p in PKG.glob("*/__init__.py")} | {"arm"}


def test_the_suite_mirrors_the_package():
    """test/unit/<room>/ (room: the fto_ros subpackage the file guards), test/system/ (whole
    commands, live nodes), test/naive/ (slow references) and test/support/ (shared helpers, no
    tests); no test file over 500 lines; every test file's name unique (pytest imports them
    by name)."""
    test = ROOT / "test"
    files = [p for p in test.rglob("*.py") if "__pycache__" not in p.parts]
    misplaced = [str(p.relative_to(test)) for p in files if p.name.startswith("test_") and not (
        (p.parent.parent == test / "unit" and p.parent.name in ROOMS)
        or p.parent in (test / "system", test / "naive"))]
    assert not misplaced, f"test files outside test/unit/<room>/, system/, naive/: {misplaced}"
    long = {str(p.relative_to(test)): n for p in files
            if (n := len(p.read_text().splitlines())) > 500}
    assert not long, f"test files over 500 lines: {long}"
    seen: dict[str, list[str]] = {}
    for p in files:
        if p.name.startswith("test_"):
            seen.setdefault(p.name, []).append(str(p.relative_to(test)))
    assert not {k: v for k, v in seen.items() if len(v) > 1}, "test files named alike"


MARKDOWN = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    return {_anchor(m.group(1)) for m in re.finditer(r"^#{1,6} +(.+?) *$", text, flags=re.M)}


@pytest.mark.parametrize("page", MARKDOWN, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_and_anchors_resolve(page):
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue                                   # http(s), mailto: not checked here
        file, _, anchor = target.partition("#")
        dest = (page.parent / file).resolve() if file else page
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: broken links {broken}"


def _prose_sentences(path: Path) -> set[str]:
    """The sentences of a markdown file's prose (no code, tables, headings or images),
    normalised, of at least 8 words."""
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    keep = [line for line in text.splitlines()
            if not line.lstrip().startswith(("|", "#", "![", "<!--"))]
    prose = " ".join(" ".join(keep).split())
    sentences = re.split(r"(?<=[.!?;:])\s+", prose)
    return {s.lower() for s in sentences if len(s.split()) >= 8}


def test_readme_and_docs_do_not_repeat_each_other():
    """The README says what the package is for and links to docs/; docs/ holds the details.
    A sentence written twice drifts apart."""
    readme = _prose_sentences(ROOT / "README.md")
    repeated = {}
    for page in sorted(DOCS.glob("*.md")):
        both = readme & _prose_sentences(page)
        if both:
            repeated[page.name] = sorted(both)
    assert not repeated, f"text repeated between README.md and docs/: {repeated}"
