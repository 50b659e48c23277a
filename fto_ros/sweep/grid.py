"""The parameter grid of a sweep: reading ``--set NAME=V1,V2,...`` and expanding it.

Each value is read exactly as ``fto-replay --set NAME=VALUE`` reads one (YAML, as ROS reads
``-p NAME:=VALUE``, through :func:`~fto_ros.runner.params_file.parse_override`), so a list
value stays possible: the value list is split on the commas that are outside brackets,
braces and quotes (``--set luenberger.process_noise=[1e-6, 0.25, 0.04],[1e-6, 1.0, 0.04]``
is two values).  The grid is every combination of the values, the first ``--set`` varying
slowest (``itertools.product`` order), which is also the order of the rows.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

from ..core.errors import BadArgument, ConfigError, short
from ..runner.params_file import parse_override

_OPEN, _CLOSE = "[{(", "]})"


@dataclass(frozen=True)
class Axis:
    """One swept parameter: its full name and its values (as typed, and as read)."""

    name: str
    texts: tuple[str, ...]
    values: tuple[Any, ...]


def split_values(text: str) -> list[str]:
    """``'1,[2, 3],"a,b"'`` -> ``['1', '[2, 3]', '"a,b"']``: split on the commas outside
    brackets, braces, parentheses and quotes; each piece stripped.  ValueError for
    unbalanced brackets or quotes."""
    pieces, depth, quote, start = [], 0, None, 0
    for i, ch in enumerate(text):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch in _OPEN:
            depth += 1
        elif ch in _CLOSE:
            depth -= 1
            if depth < 0:
                raise BadArgument(f"unbalanced '{ch}'")
        elif ch == "," and depth == 0:
            pieces.append(text[start:i].strip())
            start = i + 1
    if quote or depth:
        raise BadArgument("unbalanced quote" if quote else "unclosed bracket")
    pieces.append(text[start:].strip())
    return pieces


def parse_axis(text: str) -> Axis:
    """``'single_delay.tau=0.05,0.1'`` -> Axis; ConfigError (one line) when malformed."""
    name, sep, rest = text.partition("=")
    name = name.rstrip(":").strip()
    if not sep or not name:
        raise ConfigError("--set", f"expected NAME=V1,V2,..., got {short(text)}")
    try:
        texts = split_values(rest)
    except ValueError as err:
        raise ConfigError(name, f"cannot split the values {short(rest)}: {err}") from None
    if any(not t for t in texts):
        raise ConfigError(name, f"empty value in {short(rest)} (a stray comma?)")
    values = [parse_override(f"{name}={t}")[1] for t in texts]
    for i, v in enumerate(values):
        for j in range(i):
            if type(values[j]) is type(v) and values[j] == v:
                raise ConfigError(name, f"the value {short(texts[i])} is given twice")
    return Axis(name, tuple(texts), tuple(values))


def parse_axes(texts: Iterable[str]) -> list[Axis]:
    """Every ``--set``; ConfigError for a malformed one or a name given twice."""
    axes: list[Axis] = []
    for text in texts:
        axis = parse_axis(text)
        if any(a.name == axis.name for a in axes):
            raise ConfigError(axis.name, "given in two --set options; list its values in one")
        axes.append(axis)
    return axes


@dataclass(frozen=True)
class Setting:
    """One point of the grid: ``{name: value}`` overrides, with the values as typed."""

    overrides: Mapping[str, Any]
    texts: Mapping[str, str]

    def label(self) -> str:
        """``'single_delay.tau=0.05 single_delay.k=200'`` (``'(params as given)'`` if empty)."""
        return " ".join(f"{k}={v}" for k, v in self.texts.items()) or "(params as given)"


def expand(axes: Sequence[Axis]) -> list[Setting]:
    """Every combination of the axes' values, the first axis varying slowest; one empty
    setting (the params files as they are) when there is no axis."""
    out = []
    for combo in itertools.product(*(range(len(a.values)) for a in axes)):
        out.append(Setting({a.name: a.values[i] for a, i in zip(axes, combo)},
                           {a.name: a.texts[i] for a, i in zip(axes, combo)}))
    return out


def known_names(observer_types: Iterable[str]) -> set[str]:
    """The full parameter names the node declares for these observer types (the runner's
    settings, ROS's own, and each type's section), as the live node builds them."""
    from ..observers import observer_class
    from ..runner.settings import ROS_BUILTIN, SETTINGS
    names = {p.name for p in SETTINGS} | set(ROS_BUILTIN)
    for t in observer_types:
        cls = observer_class(t)
        names |= {f"{cls.TYPE}.{p.name}" for p in cls.PARAMS}
    return names


def check_axes(axes: Sequence[Axis], flat: Mapping[str, Any]) -> None:
    """Refuse (ConfigError) a swept name no run would use: neither a parameter of the
    observer type(s) of the sweep nor a name the params files already set."""
    types = {flat.get("observer.type")}
    for a in axes:
        if a.name == "observer.type":
            types |= set(a.values)
    types.discard(None)
    if not types:
        raise ConfigError("observer.type", "missing from the params files: say which observer "
                          "to run (or sweep it with --set observer.type=...)")
    for t in types:
        if not isinstance(t, str):
            raise ConfigError("observer.type", f"must be a string, got {short(t)}")
    known = known_names(sorted(types)) | set(flat)
    for a in axes:
        if a.name not in known:
            raise ConfigError(a.name, "unknown parameter for observer type "
                              + " / ".join(sorted(types))
                              + " (a typo? fto-sweep --set takes full names such as "
                                "single_delay.tau)")
