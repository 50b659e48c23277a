"""``fto-external-torque``'s arguments: the observer node's, with the arm's defaults added
where the user gave none (a -r __node:= remap; observer.type in no params file and no -p)."""
from __future__ import annotations

from ..core.errors import ConfigError
from ..runner.params_file import load_params_file

NAME = "external_torque_node"
TYPE = "external_torque"


def _has_type(args: list[str], fqn: str) -> bool:
    in_ros = False
    for i, a in enumerate(args):
        if a == "--ros-args":
            in_ros = True
        elif a == "--":
            in_ros = False
        elif in_ros and a in ("-p", "--param") and i + 1 < len(args) and \
                args[i + 1].partition(":=")[0] == "observer.type":
            return True
        elif in_ros and a == "--params-file" and i + 1 < len(args):
            try:
                if "observer.type" in load_params_file(args[i + 1], fqn):
                    return True
            except (ConfigError, OSError, ValueError):
                return True                   # the node's own check reports the file
    return False


def arm_arguments(args: list[str]) -> list[str]:
    """``args`` with ``-r __node:=external_torque_node`` and ``-p
    observer.type:=external_torque`` added where the user gave neither."""
    args = list(args)
    head = args[:args.index("--ros-args")] if "--ros-args" in args else args
    if "-h" in head or "--help" in head:
        return args
    extra = []
    if not any(a.startswith("__node:=") for a in args):
        extra += ["-r", f"__node:={NAME}"]
    name = next((a.partition(":=")[2] for a in args if a.startswith("__node:=")), NAME)
    if not _has_type(args, name):
        extra += ["-p", f"observer.type:={TYPE}"]
    return args + (["--ros-args", *extra] if extra else [])
