"""A user's repository with top-level packages named like ours (``emulator/``, ``bench/``,
with ``emulator/output/`` and ``bench/fit/`` too): a process that imports any of them
instead of ours dies at once, saying so (issue 29: ``python -m`` in that folder puts it
first on ``sys.path``)."""

from pathlib import Path

HOSTILE = 'raise ImportError("the user\'s own {name} package was imported instead of ours")\n'


def foreign_repository(folder: Path) -> Path:
    """Make ``folder`` such a repository; returns it."""
    for name in ("emulator", "emulator/output", "emulator/testing", "bench", "bench/fit"):
        (folder / name).mkdir()
        (folder / name / "__init__.py").write_text(HOSTILE.format(name=name))
    return folder
