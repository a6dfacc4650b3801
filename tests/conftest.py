import os
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from emulator.testing.scene_toml import dumps

# Tests import the helper modules of this folder (reference model, fakes, scene builders,
# repo_paths ...) as plain modules, from any sub-folder.
sys.path.insert(0, str(Path(__file__).parent))

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
