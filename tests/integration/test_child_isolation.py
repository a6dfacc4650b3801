"""Our child processes (the fit's worker, the ``--realtime-workers`` keeper, the HIL
harness's ``arva-emulate``) import our code, whatever folder the caller runs in: started
from a folder with its own top-level ``emulator/`` and ``bench/`` packages, they still
answer (issue 29; the fixture's case is in tests/emulator/testing/test_hil_outside.py)."""

from __future__ import annotations

import sys

import pytest
from foreign_repo import foreign_repository

from bench.fit.worker import Worker
from emulator.child_process import module_command
from emulator.output import kworkers


@pytest.fixture
def in_foreign_repository(tmp_path, monkeypatch):
    monkeypatch.chdir(foreign_repository(tmp_path))
    return tmp_path


def test_module_command_leaves_the_working_directory_off_sys_path():
    assert module_command("bench.fit.worker", "x") == [sys.executable, "-P", "-m", "bench.fit.worker", "x"]


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_the_fit_worker_answers_from_a_foreign_repository(in_foreign_repository):
    w = Worker()
    try:
        seconds = w.cpu()  # one round trip of the worker's protocol
        assert 0.0 <= seconds < 30.0
    finally:
        w.close()
    assert w.proc.returncode == 0


@pytest.mark.subprocess
@pytest.mark.timeout(60)
def test_the_keeper_answers_from_a_foreign_repository(in_foreign_repository):
    handle, line = kworkers.raise_workers()
    if handle is not None:
        handle.close()
        return
    # Refused for a reason of its own (no privilege, no kernel workers visible), not
    # because it could not import itself.
    assert "the keeper process ended without an answer" not in line, line
    assert line.startswith("arva-emulate: --realtime-workers: not applied (") and line.endswith("); continuing without it")
