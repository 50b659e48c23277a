"""Where an arm's URDF text comes from: a file (``plant.urdf``), a string parameter or a
``robot_description`` message's payload; the size limit is checked before anything is read
in full or parsed (ROS-free)."""
from __future__ import annotations

import os
from pathlib import Path

from ..core.errors import ConfigError, short

#: largest URDF accepted, in bytes (file or string); real arm URDFs are well under 1 MB
MAX_URDF_BYTES = 4 * 1024 * 1024


def read_source(urdf: str | os.PathLike | None, robot_description: str | None) -> tuple[str, str]:
    """(xml text, parameter name) of exactly one source, with the size checked first."""
    if (urdf is None) == (robot_description is None):
        raise ConfigError("plant.urdf", "give a URDF file (plant.urdf) or the robot_description "
                                        "string, exactly one of them")
    if robot_description is not None:
        if not isinstance(robot_description, str):
            raise ConfigError("robot_description", f"must be a string, got "
                                                   f"{type(robot_description).__name__}")
        if len(robot_description) > MAX_URDF_BYTES:
            raise ConfigError("robot_description", f"{len(robot_description)} characters: larger "
                                                   f"than the {MAX_URDF_BYTES} a URDF may have")
        return robot_description, "robot_description"
    path = Path(urdf)
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise ConfigError("plant.urdf", f"{short(str(path))} is not a file")
        if size > MAX_URDF_BYTES:
            raise ConfigError("plant.urdf", f"{short(str(path))} has {size} bytes: larger than "
                                            f"the {MAX_URDF_BYTES} a URDF may have")
        with open(path, "rb") as f:
            data = f.read(MAX_URDF_BYTES + 1)
    except OSError as err:
        raise ConfigError("plant.urdf", f"cannot read {short(str(path))}: {err.strerror}") from None
    if len(data) > MAX_URDF_BYTES:
        raise ConfigError("plant.urdf", f"{short(str(path))} is larger than {MAX_URDF_BYTES} bytes")
    try:
        return data.decode("utf-8"), "plant.urdf"
    except UnicodeDecodeError:
        raise ConfigError("plant.urdf", f"{short(str(path))} is not UTF-8 text") from None
