"""Names shared by the replay's modules: the node's fully qualified name, topic name
resolution, and the error a replay stops with."""
from __future__ import annotations

from ..core.errors import ReplayError

DEFAULT_NODE_NAME = "observer_node"


def node_fqn(node_name: str | None) -> str:
    """Fully qualified node name, ``/observer_node`` by default."""
    name = (node_name or DEFAULT_NODE_NAME).strip("/")
    if not name:
        raise ReplayError(f"invalid node name {node_name!r}")
    return "/" + name


def resolve_topic(name: str, fqn: str) -> str:
    """ROS 2 name resolution of a topic name for the node ``fqn`` (no remapping).

    ``/abs`` stays; ``~/x`` is ``<fqn>/x``; a relative ``x`` is ``<namespace>/x``.
    """
    if name.startswith("/"):
        return name
    if name.startswith("~"):
        return fqn + "/" + name[1:].lstrip("/")
    ns = fqn.rsplit("/", 1)[0]
    return f"{ns}/{name}"
