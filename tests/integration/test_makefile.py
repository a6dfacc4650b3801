"""The Makefile's two install sets: `make run` installs the runtime dependencies only,
`make test` the dev set (which includes the extras the tests exercise)."""

import shutil
import subprocess
import tomllib

import pytest
import repo_paths

ROOT = repo_paths.ROOT
DEV_ONLY = ("dask", "pyarrow", "matplotlib", "pymavlink", "pytest", "hypothesis")

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="needs make")


def dry_run(target: str) -> str:
    # -B: as if nothing were installed yet; -n: print the commands, run none.
    proc = subprocess.run(["make", "-n", "-B", target], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


@pytest.mark.subprocess
def test_make_run_installs_the_runtime_set_only():
    out = dry_run("run")
    assert "pip install --quiet -e .\n" in out
    assert "[dev]" not in out
    runtime = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert not [d for d in runtime if d.split(">")[0].split("[")[0] in DEV_ONLY]


@pytest.mark.subprocess
def test_make_test_installs_the_dev_set():
    out = dry_run("test")
    assert "pip install --quiet -e '.[dev]'\n" in out
    # The suite in two runs: on 3 workers, then the pty and timing tests alone.
    assert '-m pytest -q -n 3 --dist loadfile -m "not (pty or timing)" tests docs/examples' in out
    assert '-m pytest -q -p no:xdist -m "pty or timing" tests docs/examples' in out
