"""The ``arva`` pytest plugin (BRIEF 9): the ``arva_emulator`` and ``arva_firmware``
fixtures and ``--arva-port``. Registered by installing the project (entry point group
``pytest11``, name ``arva``); loading it starts nothing. docs/hil_testing.md, "The
fixture", is the user's guide: the handles, teardown, the ``arva-emulator-N`` folders kept
(and named in the report) when a test fails, the JUnit properties (``arva_scene``,
``arva_scene_toml``, ``arva_seed``).
"""

from __future__ import annotations

import shutil

import pytest

from emulator.testing.harness import Emulator
from emulator.testing.scene_toml import scene_text

#: Longest scene text recorded in the JUnit report (``arva_scene_toml``), bytes.
MAX_RECORDED_SCENE = 64 * 1024
_REPORT_KEY = pytest.StashKey[dict]()  # the test's reports by phase
_ARTEFACTS_KEY = pytest.StashKey[list]()  # folders of the emulators it started


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("arva", "ARVA emulator (hardware-in-the-loop)")
    group.addoption(
        "--arva-port",
        metavar="DEVICE",
        default=None,
        help="send the first receiver's stream of every arva_emulator to DEVICE (a serial "
        "adapter wired to the device under test) instead of a pty",
    )


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_makereport(item: pytest.Item, call):
    outcome = yield
    report = outcome.get_result()
    item.stash.setdefault(_REPORT_KEY, {})[report.when] = report
    folders = item.stash.get(_ARTEFACTS_KEY, None)
    if report.failed and folders and report.when in ("setup", "call"):
        report.sections.append(
            ("arva emulator artefacts", "streams' bytes and control transcript kept in:\n" + "\n".join(map(str, folders)))
        )


def recorded_scene_text(path: str | None) -> str:
    """The scene's text for the JUnit report (at most :data:`MAX_RECORDED_SCENE` bytes)."""
    try:
        text = scene_text(path)
    except (OSError, ValueError) as exc:
        return f"<not readable: {exc}>"
    size = len(text.encode("utf-8"))
    return text if size <= MAX_RECORDED_SCENE else f"<{size} bytes: longer than {MAX_RECORDED_SCENE}, not recorded>"


def _factory(request: pytest.FixtureRequest, tmp_path, prefix: str, launch):
    """What both fixtures do: ``start(...)`` is ``launch(work, n, ...)`` in the next
    ``PREFIX-n`` folder of ``tmp_path`` (n: how many it started before); at teardown stop
    everything started, keep the folders only when the test failed, then raise the first
    error a stop raised."""
    started: list = []
    folders: list = request.node.stash.setdefault(_ARTEFACTS_KEY, [])

    def start(*args, **kwargs):
        work = tmp_path / f"{prefix}-{len(started)}"
        folders.append(work)
        started.append(launch(work, len(started), *args, **kwargs))
        return started[-1]

    yield start
    errors = []
    for thing in started:
        try:
            thing.stop()
        except Exception as exc:  # noqa: BLE001 - stop every one, report after
            errors.append(exc)
    reports = request.node.stash.get(_REPORT_KEY, {})
    if not any(r.failed for r in reports.values()):
        for work in folders:
            shutil.rmtree(work, ignore_errors=True)
        folders.clear()
    if errors:
        raise errors[0]


@pytest.fixture
def arva_emulator(request: pytest.FixtureRequest, tmp_path):
    """A factory: ``arva_emulator(scene=None, clock="step", speed=1.0)`` -> Emulator."""
    device = request.config.getoption("--arva-port")

    def launch(work, n: int, scene=None, clock: str = "step", speed: float = 1.0) -> Emulator:
        emu = Emulator.start(scene, clock=clock, speed=speed, workdir=work, arva_port=device)
        suffix = f"_{n}" if n else ""
        # What record_property does, without its warning under junit_family xunit2
        # (pytest's default), which writes these properties all the same.
        source = "<embedded default.toml>" if scene is None else "<dict>" if isinstance(scene, dict) else str(scene)
        request.node.user_properties.append((f"arva_scene{suffix}", source))
        request.node.user_properties.append((f"arva_scene_toml{suffix}", recorded_scene_text(emu.scene_path)))
        request.node.user_properties.append((f"arva_seed{suffix}", emu.seed))
        return emu

    yield from _factory(request, tmp_path, "arva-emulator", launch)


@pytest.fixture
def arva_firmware(request: pytest.FixtureRequest, tmp_path):
    """A factory: ``arva_firmware(firmware, scene=None, clock="step", speed=1.0,
    machine="mps2-an385", icount=None)`` -> FirmwareLoop: QEMU runs the firmware ELF, the
    emulator writes the first receiver's stream into its UART0 (emulator.testing.qemu)."""
    from emulator.testing.qemu import FirmwareLoop

    def launch(work, n, firmware, scene=None, clock="step", speed=1.0, machine="mps2-an385", icount=None):
        return FirmwareLoop.start(firmware, scene, clock=clock, speed=speed, workdir=work, machine=machine,
                                  icount=icount)

    yield from _factory(request, tmp_path, "arva-firmware", launch)
