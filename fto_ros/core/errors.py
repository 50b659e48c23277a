"""Every exception fto_ros raises, in one family: ``FtoRosError`` and its subclasses, all
declared here (a caller catches one type, or the one it expects: each subclass that
replaces a builtin error keeps that builtin as a mixin, so ``except ValueError`` still
catches a ConfigError), and the helper that keeps any value quoted in a message short.

test/unit/core/test_error_family.py fails on a ``raise`` of a builtin exception class or
of any class not from this module.
"""
import argparse
import reprlib

#: longest message a ConfigError carries (characters); longer ones are cut with a note
MAX_MESSAGE = 600

_repr = reprlib.Repr()
_repr.maxstring = 80
_repr.maxother = 80
_repr.maxlist = _repr.maxtuple = _repr.maxdict = _repr.maxset = 8
_repr.maxlevel = 3


def short(value) -> str:
    """A bounded-length rendering of ``value`` for messages: an exception as its text on
    one line (cut), anything else as a shortened repr (strings quoted).  Never walks or
    prints a huge value whole."""
    if isinstance(value, BaseException):
        text = " ".join(str(value)[:10 * MAX_MESSAGE].split())
        return text if len(text) <= 200 else text[:197] + "..."
    return _repr.repr(value)


class FtoRosError(Exception):
    """The base of every exception this package raises on purpose: unusable parameters
    (ConfigError), an unusable bag (BagError), a replay or a sweep that cannot go on
    (ReplayError, EngineError), an output folder it must not write (OutputError), a plant
    whose structure it cannot use (StructureError), a sample an observer cannot take
    (SampleRejected), a value a function cannot use (BadArgument), a simulation that
    cannot go on (SimulationFailed), a payload that is not what its type says (DecodeError), a call the object does not support (UsageError,
    NotReady), a command-line value (CommandLineError), a name nothing is registered
    under (UnknownName)."""


class ConfigError(FtoRosError, ValueError):
    """A parameter value is unusable.  The message names the parameter (one line, bounded)."""

    def __init__(self, parameter: str, problem: str):
        parameter = " ".join(str(parameter)[:200].split())
        problem = " ".join(str(problem).split())
        if len(problem) > MAX_MESSAGE:
            problem = problem[:MAX_MESSAGE - 3] + "..."
        super().__init__(f"parameter '{parameter}': {problem}")
        self.parameter = parameter
        self.problem = problem


class ConfigNote(UserWarning):
    """A note to the user about a configuration that is accepted (e.g. a term counted
    twice, a paper's condition that fails but is not required): warned at start-up.  The
    runner passes these on and drops every other warning raised while an observer is
    designed (numerical ones, which the design handles)."""


class StructureError(FtoRosError, ValueError):
    """The plant fails a structural condition; ``condition`` is a short tag."""

    def __init__(self, condition: str, message: str):
        super().__init__(message)
        self.condition = condition


class SampleRejected(FtoRosError, ValueError):
    """A sample an estimator cannot use (an observer's ``update``, the arm's estimators).

    The estimator leaves its state untouched when it raises this (it computes the new state
    first and commits it only when it is finite), so a bad sample can never corrupt the
    estimate.  ``reason`` is a short snake_case tag counted in the diagnostics (or, from
    the arm's estimators, a one-line description)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class BadArgument(FtoRosError, ValueError):
    """A value passed to a function of the package that it cannot use (a wrong length, not
    finite, out of range, an unknown choice): a caller's mistake or numbers out of range
    reaching a library call.  A named parameter of a params file is a ConfigError."""


class SimulationFailed(FtoRosError, ValueError):
    """A simulation cannot go on (the integrator failed, the state became non-finite)."""


class DecodeError(FtoRosError, ValueError):
    """A serialised message that is not what its type says (truncated, a length beyond the
    payload, text that is not UTF-8)."""


class UsageError(FtoRosError, TypeError):
    """A call the object does not support (one sample at a time on a runner of several
    joints, an unknown parameter kind in a schema)."""


class NotReady(FtoRosError, RuntimeError):
    """A method called before the object was made ready for it (a differentiator stepped
    before its reset)."""


class UnknownName(FtoRosError, KeyError):
    """A name nothing is registered under; the message lists the known ones."""

    def __str__(self) -> str:             # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class CommandLineError(FtoRosError, argparse.ArgumentTypeError):
    """A command-line value an argument's type refuses (argparse prints it as the error)."""


class BagError(FtoRosError):
    """A bag cannot be read or written; the message names the path and the problem."""


class NotFast(FtoRosError):
    """The fast MCAP path (bag/mcap_scan.py) cannot read this bag; use BagReader."""


class ReplayError(FtoRosError):
    """The replay cannot run (e.g. the bag lacks a topic the configuration needs)."""


class OutputError(FtoRosError, ValueError):
    """An output path is refused (a bad argument: exit code 2; core/output_dir.py)."""


class OutputExists(FtoRosError, FileExistsError):
    """The output exists and replacing it was not asked for."""


class OutputIncomplete(FtoRosError, OSError):
    """An output could not be completed (exit code 1); the message says what became of it."""


class CacheError(FtoRosError):
    """A cache folder or file that is not used (core/private_cache.py): not this user's
    private one (another owner, writable by others, a symlink), damaged, or not usable for
    a function.  ``path`` names it when known, ``why`` says why.  Not an OSError: numba's
    loader, which takes an OSError for a missing file, must not swallow it."""

    def __init__(self, why: str, path: str | None = None):
        super().__init__(f"{path}: {why}" if path else why)
        self.path, self.why = path, why


class EngineError(FtoRosError):
    """A sweep's engine cannot run anything (scheduler unreachable, no worker, workers
    without fto_ros, files the workers cannot see).  One line."""
