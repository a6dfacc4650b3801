"""Every benchmark and study script in tests/perf answers ``--help`` (exit 0, a usage line):
it imports, with the repository's packages, and says how to run it. Five of them had
stopped importing once (a tests/ folder shadowed the package) and nobody noticed until
``make bench`` ran."""

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import pytest

import repo_paths

pytestmark = [pytest.mark.slow, pytest.mark.subprocess]

SCRIPTS = sorted(p for p in repo_paths.PERF.glob("*.py") if 'if __name__ == "__main__"' in p.read_text())


def help_of(path):
    proc = subprocess.run([sys.executable, str(path), "--help"], capture_output=True, text=True, timeout=120,
                          cwd=repo_paths.ROOT)
    return path.name, proc.returncode, proc.stdout, proc.stderr


def test_every_perf_script_answers_help():
    assert len(SCRIPTS) >= 30  # (32 on 2026-12-05)
    with ThreadPoolExecutor(3) as pool:  # each one imports numpy and the packages: ~1 s
        results = list(pool.map(help_of, SCRIPTS))
    failed = [(name, code, err.strip().splitlines()[-1:]) for name, code, out, err in results
              if code != 0 or not out.startswith(f"usage: {name}")]
    assert failed == []
