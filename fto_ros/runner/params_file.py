"""Reading ROS 2 params files as ROS does, safely, for the replay tools and the node alike.

One node's parameters come from one or several params files (``--params-file`` may be
given more than once: a shared plant file plus a tuning file), merged in order, later
files overriding earlier ones, then from ``NAME=VALUE`` overrides (``-p NAME:=VALUE``,
``fto-sweep --set``).  Within a file the ``/**`` block applies to every node and the
block named after the node overrides it; a block for another node is ignored, as rcl
ignores it, and a file with nothing for the node is refused.

Every value is read as rcl reads it (:mod:`fto_ros.runner.ros_yaml`: the type of each
scalar from its text, ``1e-300`` a double, ``~`` a string), so the replay accepts what the
node accepts.  The YAML is read defensively: files larger than :data:`MAX_BYTES`, and
(ros_yaml) nesting deeper than its ``MAX_DEPTH``, lists or mappings longer than its
``MAX_ITEMS``, anchors and aliases (which rcl's parser does not accept either, and which
expand to gigabytes when printed), and lists mixing types (which rcl refuses with an
opaque message) are refused with one line naming the file, the parameter and the element.
ROS-free.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

from ..core.errors import ConfigError, short
from .ros_yaml import read_text

DEFAULT_NODE_NAME = "observer_node"
#: largest params file read (bytes)
MAX_BYTES = 4 << 20


def read_yaml(path: str | Path) -> Any:
    """The YAML document in ``path`` read as rcl reads it (ros_yaml.py), or
    ConfigError('params file', ...) in one line."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError("params file", f"{p} does not exist or is not a file")
    try:
        if p.stat().st_size > MAX_BYTES:
            raise ConfigError("params file", f"{p} is larger than {MAX_BYTES >> 20} MB")
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError("params file", f"cannot read {p}: {short(exc)}") from None
    return read_text(text, str(p))


def _blocks(doc: Any, p: Path) -> dict[str, dict]:
    if not isinstance(doc, dict) or not doc:
        raise ConfigError("params file", f"{p} must map a node name to 'ros__parameters'")
    blocks = {}
    for key, block in doc.items():
        name = str(key).strip("/")
        if not isinstance(block, dict) or not isinstance(block.get("ros__parameters"), dict):
            raise ConfigError("params file", f"{p}: the block {short(key)} needs a "
                              "'ros__parameters' mapping")
        blocks[name] = block["ros__parameters"]
    return blocks


def _matches(key: str, fqn: str) -> bool:
    """Whether the block ``key`` applies to the node ``fqn`` (both without leading '/'):
    the exact name, ``**``, or ``**/<name>`` (any namespace)."""
    if key in ("**", fqn):
        return True
    return key.startswith("**/") and (fqn == key[3:] or fqn.endswith("/" + key[3:]))


def load_params_file(path: str | Path, node_name: str | None = None) -> dict[str, Any]:
    """The flat ``{dotted.name: value}`` parameters of the node ``node_name`` (default
    ``observer_node``) in one ROS 2 params file.

    As ROS does: the wildcard blocks first, the node's own block overrides them; blocks
    of other nodes are ignored.  ConfigError for a missing or malformed file, or one with
    no block for the node.
    """
    p = Path(path)
    blocks = _blocks(read_yaml(p), p)
    fqn = (node_name or DEFAULT_NODE_NAME).strip("/")
    # the less specific first: '**', then '**/<name>', the node's exact block last
    keys = sorted((k for k in blocks if _matches(k, fqn)), key=lambda k: (k == fqn, k != "**"))
    if not keys:
        raise ConfigError("params file", f"{p} has blocks {sorted(blocks)}; none is for node "
                          f"'/{fqn}' (name the block '{fqn}' or '/**', or choose the node name: "
                          "--node-name for the replay tools, --ros-args -r __node:=NAME for the "
                          "node)")
    flat: dict[str, Any] = {}
    for k in keys:
        flat.update(flatten(blocks[k]))
    return flat


def load_params_files(paths: Iterable[str | Path], node_name: str | None = None,
                      overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Several params files merged in order (later files override earlier ones, parameter
    by parameter, as ROS merges several ``--params-file``), then ``overrides``."""
    paths = list(paths)
    if not paths:
        raise ConfigError("params file", "no params file given")
    flat: dict[str, Any] = {}
    for path in paths:
        flat.update(load_params_file(path, node_name))
    flat.update(overrides or {})
    return flat


def parse_override(text: str) -> tuple[str, Any]:
    """``'single_delay.tau=0.05'`` -> ``('single_delay.tau', 0.05)``; the value is read as rcl
    reads ``-p NAME:=VALUE`` (ros_yaml.py: ``1e-300`` a double, ``[]`` not set).  ConfigError
    for a malformed one."""
    name, sep, value = text.partition("=")
    name = name.rstrip(":").strip()
    if not sep or not name:
        raise ConfigError("override", f"expected NAME=VALUE, got {short(text)}")
    if not value.strip():
        raise ConfigError(name, "no value (write '' for an empty string)")
    parsed = read_text(value, "the value", name)
    if isinstance(parsed, dict):
        raise ConfigError(name, f"expected a value, got a mapping {short(value)}")
    return name, parsed


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{'a': {'b': 1}}`` -> ``{'a.b': 1}`` (ROS 2's nested parameter names)."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out
