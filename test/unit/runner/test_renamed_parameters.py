"""A parameter that was renamed or replaced (runner/settings.py RENAMED, CHANGELOG.md) is
refused in one line that names it and says what to write instead; CHANGELOG.md lists every
one of them."""
from __future__ import annotations

from pathlib import Path

import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.runner import Runner
from fto_ros.runner.settings import RENAMED

ROOT = Path(__file__).resolve().parents[3]
ARM = {"observer.type": "external_torque", "plant.urdf": str(ROOT / "urdf" / "arm7.urdf")}
DC = {"observer.type": "luenberger", "luenberger.A": [[0.0, 1.0], [0.0, 0.0]],
      "luenberger.B": [[0.0], [1.0]], "luenberger.C": [[1.0, 0.0]], "luenberger.poles": [-5.0, -6.0]}


@pytest.mark.parametrize("old", sorted(RENAMED))
@pytest.mark.parametrize("base", [ARM, DC], ids=["arm", "classic"])
def test_an_old_name_is_refused_naming_the_new_one(old, base):
    with pytest.raises(ConfigError) as err:
        Runner({**base, old: 1.0})
    assert err.value.parameter == old
    assert "no longer a parameter" in str(err.value) and RENAMED[old] in str(err.value)


def test_the_changelog_lists_every_renamed_parameter():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert [old for old in RENAMED if f"`{old}`" not in text] == []
