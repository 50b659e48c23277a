"""What the command-line tools share: argparse value types (clear messages, exit code 2),
one-line error messages, and the guard around a tool's body (no traceback, 130 on Ctrl-C)."""
from __future__ import annotations

import argparse
import math
import os
import sys
from typing import Callable

from .errors import CommandLineError


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise CommandLineError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise CommandLineError(f"must be finite, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _number(text)
    if value <= 0:
        raise CommandLineError(f"must be a finite number > 0, got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    value = _number(text)
    if value < 0:
        raise CommandLineError(f"must be a finite number >= 0, got {text!r}")
    return value


def fraction(text: str) -> float:
    """A number in [0, 1]."""
    value = _number(text)
    if not 0.0 <= value <= 1.0:
        raise CommandLineError(f"must be a fraction in [0, 1], got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (e.g. a number of workers)."""
    try:
        value = int(text)
    except ValueError:
        raise CommandLineError(f"not an integer: {text!r}") from None
    if value < 1:
        raise CommandLineError(f"must be an integer >= 1, got {text!r}")
    return value


def one_line(err: BaseException | str) -> str:
    """An error message on one line (YAML and other parsers give several), bounded."""
    text = " ".join(str(err)[:4000].split())
    return text if len(text) <= 1000 else text[:997] + "..."


def guarded(prog: str, body: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """``body(args)``'s exit code; 130 on Ctrl-C; an unexpected exception is one
    ``PROG: error: unexpected ...`` line and exit code 1 (``FTO_DEBUG=1`` raises it)."""
    try:
        return body(args)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # never a traceback for the user
        if os.environ.get("FTO_DEBUG"):
            raise
        print(f"{prog}: error: unexpected {type(err).__name__}: {one_line(err)} "
              "(FTO_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1
