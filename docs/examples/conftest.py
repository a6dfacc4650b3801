"""For this repository's own suite only: the example starts arva-emulate and its device
under test as processes, so `make test-fast` (which deselects the `subprocess` marker,
registered in pyproject.toml) leaves it out. The example file itself stays as a user would
copy it."""

import pytest


def pytest_collection_modifyitems(config, items):
    here = config.rootpath / "docs" / "examples"
    for item in items:
        if item.path.is_relative_to(here):
            item.add_marker(pytest.mark.subprocess)
