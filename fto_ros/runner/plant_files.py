"""One plant file, several tuning files: which params files a tuning file is run with.

Convention (fto-report, the tests and the docs follow it): in a config directory,
``<system>_plant.yaml`` holds the plant block of ``<system>`` (and the I/O settings its
tuning files share).  It is not a tuning file itself.  Every other ``<system>_*.yaml`` is
a tuning file; it runs with the plant file merged first (as ``--params-file plant
--params-file tuning``) unless it carries a model of its own: a plant block of its own
(``plant.states``), or one of the parameters its observer would derive from the plant (the
explicit form, e.g. ``single_delay.A1``), or the URDF of an arm's external-torque family
(``plant.urdf``, ``robot_description``).  Other ``plant.*`` parameters amend the plant
file's (config/arm7_hosm.yaml: the joint model without its Coulomb friction).  ``<system>`` is the longest prefix of the tuning file's name that has
a plant file.  ROS-free.
"""
from __future__ import annotations

from pathlib import Path

from ..plant import DERIVES
from ..plant.block import PREFIX
from .params_file import load_params_file

#: suffix of a plant file's stem
PLANT_SUFFIX = "_plant"


def is_plant_file(path: Path) -> bool:
    return Path(path).stem.endswith(PLANT_SUFFIX)


def system_plant_file(path: Path) -> Path | None:
    """The plant file of the system ``path`` belongs to (the longest prefix of its name
    with one), or None; a plant file has none."""
    path = Path(path)
    if is_plant_file(path):
        return None
    parts = path.stem.split("_")
    candidates = (path.with_name("_".join(parts[:k]) + PLANT_SUFFIX + ".yaml")
                  for k in range(len(parts) - 1, 0, -1))
    return next((p for p in candidates if p.is_file()), None)


def plant_file_for(tuning: Path) -> Path | None:
    """The plant file ``tuning`` runs with, or None (see the module doc).  A tuning file
    that cannot be read gets its plant file when one exists: the replay reports the
    problem."""
    plant = system_plant_file(tuning)
    if plant is None:
        return None
    try:
        flat = load_params_file(tuning)
    except ValueError:
        return plant
    kind = flat.get("observer.type")
    own = {f"{kind}.{k}" for k in DERIVES.get(kind, ())}
    if any(k == PREFIX + "states" or k in own for k in flat):
        return None
    if any(k in ("plant.urdf", "robot_description") for k in flat):
        return None                     # an arm family's model: its URDF
    return plant


def params_files(tuning: Path) -> list[Path]:
    """[plant file, tuning file], or [tuning file] when it needs no plant file."""
    plant = plant_file_for(tuning)
    return [Path(tuning)] if plant is None else [plant, Path(tuning)]
