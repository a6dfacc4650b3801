"""The ``arva`` pytest plugin (BRIEF 9): the ``arva_emulator`` fixture and ``--arva-port``.

Registered by installing the project (entry point group ``pytest11``, name ``arva``);
docs/hil_testing.md, "The fixture", is the user's guide. ``arva_emulator(scene=None,
clock="step", speed=1.0)`` starts ``arva-emulate --port pty --control ...`` and returns an
:class:`~emulator.testing.harness.Emulator`; ``arva_firmware(firmware, ...)`` runs a
firmware ELF on QEMU (:mod:`emulator.testing.qemu`) and returns a ``FirmwareLoop``. Every
emulator a test started is stopped at teardown; its folder (``arva-emulator-N``,
``arva-firmware-N`` under ``tmp_path``: stream captures, control transcript) is kept and
named in the report when the test fails, else removed. The scene and its seed are
recorded as test properties, as ``record_property`` does (``arva_scene``,
``arva_scene_toml``: the text the emulator read, ``arva_seed``; ``_1``, ``_2`` ... for
further emulators of the same test). Loading the plugin starts nothing.
"""

from __future__ import annotations

import shutil

import pytest

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


def _stop_all(request: pytest.FixtureRequest, started: list, folders: list) -> None:
    """Teardown shared by the fixtures: stop everything started, keep the artefact folders
    only when the test failed, then raise the first error a stop raised."""
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


def recorded_scene_text(path: str | None) -> str:
    """The scene's text for the JUnit report (at most :data:`MAX_RECORDED_SCENE` bytes)."""
    from emulator.testing.scene_toml import scene_text

    try:
        text = scene_text(path)
    except (OSError, ValueError) as exc:
        return f"<not readable: {exc}>"
    size = len(text.encode("utf-8"))
    return text if size <= MAX_RECORDED_SCENE else f"<{size} bytes: longer than {MAX_RECORDED_SCENE}, not recorded>"


@pytest.fixture
def arva_emulator(request: pytest.FixtureRequest, tmp_path):
    """A factory: ``arva_emulator(scene=None, clock="step", speed=1.0)`` -> Emulator."""
    from emulator.testing.harness import Emulator

    started: list[Emulator] = []
    folders: list = request.node.stash.setdefault(_ARTEFACTS_KEY, [])
    device = request.config.getoption("--arva-port")

    def start(scene=None, clock: str = "step", speed: float = 1.0) -> Emulator:
        work = tmp_path / f"arva-emulator-{len(started)}"
        folders.append(work)
        emu = Emulator.start(scene, clock=clock, speed=speed, workdir=work, arva_port=device)
        started.append(emu)
        suffix = "" if len(started) == 1 else f"_{len(started) - 1}"
        # What record_property does, without its warning under junit_family xunit2
        # (pytest's default), which writes these properties all the same.
        source = "<embedded default.toml>" if scene is None else "<dict>" if isinstance(scene, dict) else str(scene)
        request.node.user_properties.append((f"arva_scene{suffix}", source))
        request.node.user_properties.append((f"arva_scene_toml{suffix}", recorded_scene_text(emu.scene_path)))
        request.node.user_properties.append((f"arva_seed{suffix}", emu.seed))
        return emu

    yield start
    _stop_all(request, started, folders)


@pytest.fixture
def arva_firmware(request: pytest.FixtureRequest, tmp_path):
    """A factory: ``arva_firmware(firmware, scene=None, clock="step", speed=1.0,
    machine="mps2-an385", icount=None)`` -> FirmwareLoop: QEMU runs the firmware ELF, the
    emulator writes the first receiver's stream into its UART0 (emulator.testing.qemu)."""
    from emulator.testing.qemu import FirmwareLoop

    started: list[FirmwareLoop] = []
    folders: list = request.node.stash.setdefault(_ARTEFACTS_KEY, [])

    def start(firmware, scene=None, clock: str = "step", speed: float = 1.0, machine: str = "mps2-an385", icount=None):
        work = tmp_path / f"arva-firmware-{len(started)}"
        folders.append(work)
        loop = FirmwareLoop.start(firmware, scene, clock=clock, speed=speed, workdir=work, machine=machine, icount=icount)
        started.append(loop)
        return loop

    yield start
    _stop_all(request, started, folders)
