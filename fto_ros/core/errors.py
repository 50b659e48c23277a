"""The package's exception base (every error fto_ros raises is an ``FtoRosError``: a caller
catches one type), the one exception type for unusable configuration, shared by every
layer, and the helper that keeps any value quoted in a message short."""
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
    (SampleRejected)."""


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
