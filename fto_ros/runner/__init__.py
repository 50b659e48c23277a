"""The adapter shared by the live node and the replay harness (ROS-free)."""
from .runner import CONVERGENCE_FIELDS, Output, Runner
from .status import ERROR, LEVEL_NAMES, OK, WARN, Status
from .settings import SETTINGS, load_params_file

__all__ = ["CONVERGENCE_FIELDS", "ERROR", "LEVEL_NAMES", "OK", "WARN", "Output", "Runner",
           "SETTINGS", "Status", "load_params_file"]
