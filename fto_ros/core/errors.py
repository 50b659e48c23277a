"""The one exception type for unusable configuration, shared by every layer."""


class ConfigError(ValueError):
    """A parameter value is unusable.  The message names the parameter."""

    def __init__(self, parameter: str, problem: str):
        super().__init__(f"parameter '{parameter}': {problem}")
        self.parameter = parameter
        self.problem = problem
