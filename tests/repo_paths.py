"""Where things are, for tests at any depth under tests/ (imported by bare name through
tests/conftest.py's sys.path entry, like the other helper modules here)."""

from pathlib import Path

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
PERF = TESTS / "perf"
OUTSIDE = TESTS / "outside"
SCENES = ROOT / "emulator" / "scenes"
