"""The one exception type for unusable configuration, shared by every layer, and the
helper that keeps any value quoted in a message short."""
import reprlib

#: longest message a ConfigError carries (characters); longer ones are cut with a note
MAX_MESSAGE = 600

_repr = reprlib.Repr()
_repr.maxstring = 80
_repr.maxother = 80
_repr.maxlist = _repr.maxtuple = _repr.maxdict = _repr.maxset = 8
_repr.maxlevel = 3


def short(value) -> str:
    """A bounded-length rendering of ``value`` for messages: strings and exceptions as
    their text (cut), anything else as a shortened repr.  Never walks a huge value."""
    if isinstance(value, BaseException):
        value = " ".join(str(value).split())
    if isinstance(value, str):
        text = " ".join(value.split()) if len(value) < 10 * MAX_MESSAGE else value[:MAX_MESSAGE]
        return text if len(text) <= 120 else text[:117] + "..."
    return _repr.repr(value)


class ConfigError(ValueError):
    """A parameter value is unusable.  The message names the parameter (one line, bounded)."""

    def __init__(self, parameter: str, problem: str):
        parameter = short(str(parameter))
        problem = " ".join(str(problem).split())
        if len(problem) > MAX_MESSAGE:
            problem = problem[:MAX_MESSAGE - 3] + "..."
        super().__init__(f"parameter '{parameter}': {problem}")
        self.parameter = parameter
        self.problem = problem
