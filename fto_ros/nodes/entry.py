"""The command line of the observer nodes (plain and managed) and of the external-torque
node: usage, the params-file check done before rcl parses them (with the replay tools'
reader, so both refuse the same files with the same line), start-up and the exit status
(0 on shutdown, 2 on a bad parameter or argument: one log line names it).

A node that would refuse its parameters at start-up (the plain observer, the managed one
with ``autostart``, the external-torque node unless ``autostart`` is false) has its
configuration built first from the same parameters (its params files' blocks for its name,
then the ``-p`` values, read as rcl reads them): a refusal (a bad value, an unreadable URDF)
is printed before ``rclpy.init``, so before any DDS participant exists and before any
middleware line (:func:`preflight`)."""
from __future__ import annotations

import gc
import os
import sys
import tempfile
from typing import Callable, Iterator

import rclpy
import rclpy.logging
import rclpy.utilities
from rclpy.executors import ExternalShutdownException

from ..core.errors import ConfigError
from ..observers import REGISTRY
from ..runner.params_file import load_params_file, parse_override
from ..runner.runner import CONVERGENCE_FIELDS
from ..runner.settings import SETTINGS
from .fast_io import create_executor, spin

NODE_NAME = "observer_node"

USAGE = """\
usage: {prog} [-h] --ros-args --params-file PARAMS.yaml [-p NAME:=VALUE ...]
       ros2 run fto_ros {exe} --ros-args --params-file PARAMS.yaml

The fto_ros live observer node{managed} (default name: observer_node).  observer.type
chooses the observer; its parameters live under '<type>.' (see docs/ros_interface.md
and config/*.yaml).  Add -p use_sim_time:=true to run on a bag's /clock.

Subscribes   measured_output, input (Float64MultiArray; stamped on receipt)
             or joint_states (JointState; header stamp), per 'source';
             ~/set_state (JointState: every state name and its value).
Publishes    ~/state_estimate, ~/state_estimate_stamped, ~/convergence [{fields}]
             (-1 = no guarantee / unknown), ~/estimated_joint_states,
             ~/unknown_input_estimate(_stamped), /diagnostics.
Services     ~/reset (std_srvs/Trigger), ~/enable (std_srvs/SetBool),
             ~/set_state (rcl_interfaces/SetParameters: 'state' = [x...], or one per state){lifecycle}
Exit status  0 on shutdown, 2 on a bad parameter or argument (one log line names it).

observer types: {types}

runner parameters:
{params}
"""


def usage(prog: str, exe: str, managed: bool) -> str:
    lines = []
    for p in SETTINGS:
        default = "required" if p.default is None else f"default {p.default!r}"
        lines.append(f"  {p.name} ({p.kind}, {default}): {p.description}")
    types = "; ".join(f"{name} ({cls.DESCRIPTION or cls.__doc__.splitlines()[0]})"
                      for name, cls in sorted(REGISTRY.items()))
    lifecycle = ("\n             and the lifecycle services (~/change_state, ~/get_state, ...):"
                 "\n             configure, activate, deactivate, cleanup, shutdown; -p "
                 "autostart:=true\n             configures and activates at start") if managed else ""
    return USAGE.format(prog=prog, exe=exe, managed=" as a managed (lifecycle) node" if managed else "",
                        fields=", ".join(CONVERGENCE_FIELDS), types=types, lifecycle=lifecycle,
                        params="\n".join(lines))


def node_fqn(args: list[str]) -> str:
    """The node's fully qualified name after ``-r __node:=N`` / ``-r __ns:=NS`` remaps."""
    name, ns = NODE_NAME, ""
    for i, a in enumerate(args[:-1]):
        if a in ("-r", "--remap"):
            key, _, value = args[i + 1].partition(":=")
            if key == "__node" and value:
                name = value
            elif key == "__ns" and value:
                ns = value.strip("/")
    return f"{ns}/{name}" if ns else name


def ros_options(args: list[str]) -> Iterator[tuple[str, str]]:
    """(option, value) of every ``--params-file``, ``-p`` and ``--param`` inside the
    ``--ros-args ... [--]`` sections of ``args``, in order."""
    in_ros = False
    for i, a in enumerate(args):
        if a == "--ros-args":
            in_ros = True
        elif a == "--":
            in_ros = False
        elif in_ros and a in ("--params-file", "-p", "--param") and i + 1 < len(args):
            yield a, args[i + 1]


def precheck_params_files(args: list[str]) -> None:
    """Check --params-file arguments before rcl parses them (its errors are opaque), with the
    reader of the replay tools: both refuse the same files with the same line."""
    for option, value in ros_options(args):
        if option == "--params-file":
            load_params_file(value, node_fqn(args))


def command_line_params_win(args: list[str], folder: str) -> list[str]:
    """``args`` with the ``-p NAME:=VALUE`` of the command line restated, for the node, in a
    params file given last (written in ``folder``), so that they win over every params file,
    as the usage says.

    rcl merges its overrides by node entry in the order each entry first appears: a
    ``--params-file`` given before ``-p`` has its node's entry first and ``-p`` (the ``/**``
    entry) wins, but given after ``-p`` its block outranks the command line.  A node-specific
    entry written last always wins; rcl still parses the ``-p`` arguments themselves (and
    refuses a malformed one), and the values are the same text, read by the same parser."""
    pairs = []
    for option, text in ros_options(args):
        if option != "--params-file":
            name, sep, value = text.partition(":=")
            # (an empty value or a comment: rcl itself refuses or unsets it, left to it)
            if sep and name and value.strip() and not value.lstrip().startswith("#") \
                    and "\n" not in value:
                pairs.append((name, value))
    if not pairs:
        return args
    path = os.path.join(folder, "command_line_params.yaml")
    with open(path, "w") as f:
        f.write(f"/{node_fqn(args)}:\n  ros__parameters:\n")
        f.writelines(f"    {name}: {value}\n" for name, value in pairs)
    return args + ["--ros-args", "--params-file", path]


def node_parameters(args: list[str]) -> dict | None:
    """The parameters rcl will give the node, as the replay tools read them: each
    ``--params-file``'s blocks for the node's name in order, then every ``-p NAME:=VALUE``
    (which win, :func:`command_line_params_win`).  None when the command line has what this
    reading does not follow (a ``-p`` naming a node, a value rcl reads its own way): rcl and
    the node then decide, as before."""
    fqn, flat, overrides = node_fqn(args), {}, {}
    for option, text in ros_options(args):
        if option == "--params-file":
            flat.update(load_params_file(text, fqn))
            continue
        name, sep, value = text.partition(":=")
        if not sep or not name or ":" in name:
            return None
        try:
            overrides.update([parse_override(f"{name}={value}")])
        except ConfigError:
            return None
    flat.update(overrides)
    return flat


def _autostart(flat: dict, default: bool) -> bool:
    value = flat.get("autostart", default)
    return value if isinstance(value, bool) else default


def preflight(exe: str, args: list[str]) -> None:
    """Build the configuration the node ``exe`` would build at start-up from ``args``:
    ConfigError naming the parameter if it would refuse it.  Nothing for a node that
    starts unconfigured (a managed node without autostart: its configure transition
    reports), nor where :func:`node_parameters` leaves the reading to rcl."""
    flat = node_parameters(args)
    if flat is None:
        return
    if exe == "external_torque_node":
        if not _autostart(flat, True):
            return
        from ..runner.torque_settings import build
        try:
            build(flat)
        except ConfigError:
            raise
        except Exception as exc:  # noqa: BLE001  as the node's configure says it
            raise ConfigError("plant.urdf", f"cannot build the model: {type(exc).__name__}: "
                              + " ".join(str(exc).split())[:300]) from None
        return
    if exe == "managed_observer_node" and not _autostart(flat, False):
        return
    from ..runner import Runner
    try:
        Runner({k: v for k, v in flat.items() if not k.startswith("qos_overrides.")})
    except ConfigError:
        raise
    except Exception:  # noqa: BLE001  not a refusal: the node's own start reports it
        return


def _error_line(text: str) -> None:
    rclpy.logging.get_logger(NODE_NAME).error(text)


def run(make_node: Callable, prog: str, exe: str, managed: bool,
        argv: list[str] | None = None) -> int:
    """Parse the arguments, start ``make_node()`` and spin it; the exit status."""
    args = [prog] + list(sys.argv[1:] if argv is None else argv)
    head = args[1:args.index("--ros-args")] if "--ros-args" in args else args[1:]
    if "-h" in head or "--help" in head:
        print(usage(prog, exe, managed))
        return 0
    try:
        precheck_params_files(args)
        preflight(exe, args)         # a refusal before rclpy.init: no DDS participant yet
    except ConfigError as exc:
        _error_line(f"fto_ros: bad parameter: {exc}")
        return 2
    try:
        user_args = rclpy.utilities.remove_ros_args(args)[1:]
    except Exception as exc:  # rcl's own argument errors
        _error_line("fto_ros: bad arguments: " + " ".join(str(exc).split()))
        return 2
    if user_args:
        print(f"{prog}: unexpected argument(s) {user_args}; parameters go after "
              "--ros-args (see --help)", file=sys.stderr)
        return 2
    try:
        with tempfile.TemporaryDirectory(prefix="fto_ros_args_") as folder:
            rclpy.init(args=command_line_params_win(args, folder))  # rcl reads the files here
    except Exception as exc:  # rcl's argument / params-file errors
        _error_line("fto_ros: cannot start: " + " ".join(str(exc).split()))
        return 2
    node = None
    code = 0
    try:
        node = make_node()
        # the imports (sympy, scipy) leave ~1e5 long-lived objects: a full collection of
        # them takes ~50 ms, a latency spike at 1 kHz; nothing created so far is garbage
        gc.freeze()
        # the managed node is not configured yet: single (executor_kind)
        executor = create_executor(node.executor_kind() if not managed else "single")
        executor.add_node(node)
        spin(executor)
    except ConfigError as exc:
        _error_line(f"fto_ros: bad parameter: {exc}")
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # Ctrl-C while the executor builds its wait set: rclpy's signal handler shut the
        # context down and the KeyboardInterrupt went elsewhere (a __del__), so spin()
        # raises RCLError 'the given context is not valid': a shutdown too
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
