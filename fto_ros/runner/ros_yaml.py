"""YAML read as ROS 2 reads parameters: rcl's rules for every scalar, one reader for the
params files and the ``NAME=VALUE`` overrides (ROS-free).

rcl (``rcl_yaml_param_parser``, on libyaml's events) does not use YAML's schemas: it
decides the type of each scalar from its text, in this order, and so does this module:

1. tagged ``!!str``, or quoted ('...' or "..."): a string;
2. one of ``y Y yes Yes YES true True TRUE on On ON`` (or the ``n no false off`` family):
   a bool;
3. all of it read by C's ``strtoll`` in base 0 without overflow: an integer (``+1``,
   ``-0``, ``0x1F`` = 31, ``010`` = 8: a leading 0 is octal);
4. one of ``.nan .NaN .NAN .inf .Inf .INF`` (signed for inf), or all of it read by C's
   ``strtod`` without a range error: a double (``1e-300``, ``1E5``, ``1.``, ``.5``,
   ``inf``, ``nan``, ``0x1p3``; ``08`` = 8.0; ``1e400`` and ``1e-310`` are range errors);
5. anything else: a string (``1_000``, ``0b101``, ``~``, ``null``, ``tRUE``).

Other tags are ignored, as rcl ignores them.  A list holds one type (rcl refuses
``[1, 2.0]``; the refusal here names the element), an empty list is a parameter that is
not set (None, as rclpy reads it), and a key without a value is refused.  PyYAML's own
reading (YAML 1.1) differs on many of these (``1e-300`` is a string, ``1_000`` an
integer, ``~`` None), which is why it is not used for values.

Read defensively: anchors and aliases, nesting deeper than :data:`MAX_DEPTH`, lists
longer than :data:`MAX_ITEMS` and mappings with more keys are refused as soon as the
event stream shows them, before anything is built.  Test: ``test/unit/runner/test_ros_yaml.py``
compares this reader with rcl's own (a node started on the same file).
"""
from __future__ import annotations

import math
import re
from fractions import Fraction
from typing import Any

import yaml

from ..core.errors import ConfigError, short
from ..core.params import MAX_ARRAY

#: deepest nesting of mappings and lists accepted
MAX_DEPTH = 32
#: most elements in one list (an array parameter's limit), and most keys in one mapping
MAX_ITEMS = MAX_ARRAY

_TRUE = frozenset("y Y yes Yes YES true True TRUE on On ON".split())
_FALSE = frozenset("n N no No NO false False FALSE off Off OFF".split())
_SPECIAL = {s: v for v, names in ((math.nan, ".nan .NaN .NAN"),
                                  (math.inf, ".inf .Inf .INF +.inf +.Inf +.INF"),
                                  (-math.inf, "-.inf -.Inf -.INF")) for s in names.split()}
_STR_TAG = "tag:yaml.org,2002:str"
_INT64 = 2 ** 63
_SPACE = " \t\n\v\f\r"           # C's isspace in the C locale: strtoll/strtod skip it first
_INT_RE = re.compile(r"([+-]?)(?:0[xX]([0-9a-fA-F]+)|(0[0-7]*)|([1-9][0-9]*))")
_DEC_RE = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_HEX_RE = re.compile(r"([+-]?)0[xX]([0-9a-fA-F]*)(?:\.([0-9a-fA-F]*))?(?:[pP]([+-]?[0-9]+))?")
_WORD_RE = re.compile(r"[+-]?(?:inf(?:inity)?|nan(?:\([0-9A-Za-z_]*\))?)", re.IGNORECASE)
_TINY = 2.2250738585072014e-308      # the smallest normal double


def _strtoll(text: str) -> int | None:
    """C's strtoll(text, &end, 0) when it reads all of ``text`` without overflow, else None."""
    body = text.lstrip(_SPACE)
    m = _INT_RE.fullmatch(body)
    if not body or m is None:
        return None
    sign, hexa, octal, dec = m.groups()
    if len((hexa or octal or dec).lstrip("0")) > 22:   # more digits than any int64 has
        return None
    value = int(hexa, 16) if hexa is not None else int(octal, 8) if octal is not None else int(dec)
    value = -value if sign == "-" else value
    return value if -_INT64 <= value < _INT64 else None


def _strtod(text: str) -> float | None:
    """C's strtod(text, &end) (glibc, C locale) when it reads all of ``text`` and sets no
    range error (overflow, or an inexact result below the normal range), else None."""
    body = text.lstrip(_SPACE)
    if _WORD_RE.fullmatch(body):
        word = body.lstrip("+-").lower()
        value = math.nan if word.startswith("nan") else math.inf
        return -value if body.startswith("-") else value
    hexa = _HEX_RE.fullmatch(body)
    if hexa is not None and (hexa.group(2) or hexa.group(3)):
        sign, whole, frac, exp = hexa.groups()
        digits = whole + (frac or "")
        nonzero = int(digits, 16) != 0
        if exp is not None and len(exp.lstrip("+-")) > 6:    # |exponent| >= 1e6
            if nonzero:
                return None                                  # overflow or underflow: ERANGE
            value = 0.0
        else:
            try:
                value = float.fromhex(body)
            except OverflowError:
                return None

        def exact():
            return Fraction(int(digits, 16), 16 ** len(frac or "")) * Fraction(2) ** int(exp or 0)
    elif _DEC_RE.fullmatch(body):
        sign = "-" if body.startswith("-") else ""
        value = float(body)                            # correctly rounded, as glibc's
        nonzero = any(c in "123456789" for c in body.split("e")[0].split("E")[0])

        def exact():
            return Fraction(body)
    else:
        return None
    if math.isinf(value):
        return None
    value = abs(value)
    if nonzero and value < _TINY:
        try:
            if value == 0.0 or Fraction(value) != abs(exact()):
                return None                            # an inexact result below normal: ERANGE
        except ValueError:                             # thousands of digits: taken as inexact
            return None
    return -value if sign == "-" else value


def ros_scalar(text: str, style: str | None = None, tag: str | None = None) -> Any:
    """The value rcl gives the scalar ``text`` written in ``style`` (None: plain; ``"'"``,
    ``'"'`` quoted; ``|``, ``>`` block) with ``tag``: a bool, int, float or str."""
    if tag == _STR_TAG or style in ("'", '"'):
        return text
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    value = _strtoll(text)
    if value is not None:
        return value
    if text in _SPECIAL:
        return _SPECIAL[text]
    value = _strtod(text)
    return text if value is None else value


_KIND = {bool: "boolean", int: "integer", float: "decimal", str: "string"}


def _check_list(items: list, where: str) -> None:
    """rcl's rule: every element of a list has the type of the first."""
    first = type(items[0])
    for i, v in enumerate(items):
        if type(v) is not first:
            hint = (" (write every number with a decimal point, e.g. 1.0)"
                    if {first, type(v)} == {int, float} else "")
            raise ConfigError(where, f"the list mixes {_KIND[first]}s and {_KIND[type(v)]}s: "
                              f"element {i} ({short(v)}) is a {_KIND[type(v)]}, element 0 "
                              f"({short(items[0])}) a {_KIND[first]}; a ROS 2 list holds one "
                              f"type{hint}")


def _name(path: list[str]) -> str:
    """The parameter name of a key path (below ``ros__parameters`` when it is on it)."""
    if "ros__parameters" in path:
        path = path[path.index("ros__parameters") + 1:]
    return ".".join(path) or "params file"


class _Open:
    """A mapping or list being built: its key path and, in a mapping, the key read last."""

    def __init__(self, box, path: list[str]):
        self.box, self.path, self.key = box, path, None

    def child_path(self) -> list[str]:
        return self.path + [self.key] if self.key is not None else self.path


def _build(events, source: str, name: str | None) -> Any:
    """The value of one document from ``events`` (positioned after its start), up to its end;
    ``name``: the parameter the document is the value of (an override), for messages."""
    base = [name] if name else []
    stack: list[_Open] = []
    root: list = []

    def put(value, line: int, container: bool) -> None:
        if not stack:
            root.append(value)
            return
        top = stack[-1]
        if isinstance(top.box, list):
            if container:
                raise ConfigError(_name(top.path), f"{source} line {line}: element "
                                  f"{len(top.box)} is a list or a mapping; a ROS 2 parameter "
                                  "is a scalar or a flat list")
            if len(top.box) >= MAX_ITEMS:
                raise ConfigError(_name(top.path), f"{source}: a list of over {MAX_ITEMS} "
                                  f"elements: at most {MAX_ITEMS}")
            top.box.append(value)
        else:
            top.box[top.key] = value
            top.key = None

    for event in events:
        line = event.start_mark.line + 1
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None):
            raise ConfigError("params file", f"{source} line {line}: YAML anchors and aliases "
                              "(&, *) are not supported in params files; write the values out")
        top = stack[-1] if stack else None
        if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            if top is not None and isinstance(top.box, dict) and top.key is None:
                raise ConfigError(_name(top.path), f"{source} line {line}: a key must be a name")
            if len(stack) >= MAX_DEPTH:
                raise ConfigError("params file", f"{source}: nested deeper than {MAX_DEPTH} levels")
            box = {} if isinstance(event, yaml.MappingStartEvent) else []
            stack.append(_Open(box, top.child_path() if top is not None else base))
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            done = stack.pop()
            value = done.box
            if isinstance(value, list):
                if value:
                    _check_list(value, _name(done.path))
                value = value or None                  # [] is a parameter not set, as in rcl
            put(value, line, container=True)
        elif isinstance(event, yaml.ScalarEvent):
            if top is not None and isinstance(top.box, dict) and top.key is None:   # a key
                if event.value in top.box:
                    raise ConfigError(_name(top.path + [event.value]), f"{source} line {line}: "
                                      "given twice")
                if len(top.box) >= MAX_ITEMS:
                    raise ConfigError(_name(top.path), f"{source}: a mapping of over "
                                      f"{MAX_ITEMS} keys: at most {MAX_ITEMS}")
                top.key = event.value
                continue
            style = event.style or None                # libyaml says '' for plain
            if style is None and event.value == "":
                where = _name(top.child_path() if top is not None else base)
                raise ConfigError(where, f"{source} line {line}: no value (write '' for an empty "
                                  "string, [] for an empty list)")
            put(ros_scalar(event.value, style, event.tag), line, container=False)
        elif isinstance(event, yaml.DocumentEndEvent):
            break
    return root[0] if root else None


_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)     # libyaml, as rcl, when present


def read_text(text: str, source: str, name: str | None = None) -> Any:
    """The one YAML document in ``text`` read as rcl reads it (mappings of text keys, lists
    of one type, scalars by :func:`ros_scalar`); None for an empty document.  ConfigError
    naming ``source`` (the parameter ``name`` for an override's value) for invalid YAML,
    several documents, or anything refused above."""
    try:
        events = iter(yaml.parse(text, Loader=_Loader))
        docs = 0
        value = None
        for event in events:
            if isinstance(event, yaml.DocumentStartEvent):
                docs += 1
                if docs > 1:
                    raise ConfigError("params file", f"{source} holds more than one YAML document")
                value = _build(events, source, name)
        return value
    except yaml.YAMLError as exc:
        if "nesting depth" in str(exc):                # libyaml's own limit, deeper than ours
            raise ConfigError("params file", f"{source}: nested deeper than {MAX_DEPTH} "
                              "levels") from None
        raise ConfigError("params file", f"{source} is not valid YAML: {short(exc)}") from None
