import os
import sys
from pathlib import Path

# Tests import the helper modules of this folder (reference model, fakes, scene builders,
# repo_paths ...) as plain modules, from any sub-folder. The repository root goes before
# this folder: tests/emulator, tests/bench and tests/firmware_proto (no __init__.py) would
# otherwise be found as namespace packages in place of the real ones by a plain `pytest`
# run (the editable install's finder comes after sys.path; `python -m pytest` has the
# root on sys.path already).
_TESTS = Path(__file__).resolve().parent
for _entry in (str(_TESTS), str(_TESTS.parent)):
    while _entry in sys.path:
        sys.path.remove(_entry)
sys.path[:0] = [str(_TESTS.parent), str(_TESTS)]

import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

from emulator.testing.scene_toml import dumps  # noqa: E402

settings.register_profile("ci", max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", max_examples=100, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture
def scene_file(tmp_path):
    """``scene_file(scene, name="s.toml") -> str``: writes a scene (a dict, e.g. from
    scene_builders, as TOML through emulator.testing.scene_toml; or TOML text as it is) to
    ``tmp_path / name`` and returns that path."""
    def write(scene: dict | str, name: str = "s.toml") -> str:
        path = tmp_path / name
        path.write_text(scene if isinstance(scene, str) else dumps(scene))
        return str(path)

    return write
