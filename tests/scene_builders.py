"""The scenes many tests start from, built once (BRIEF 3 keys; positions in metres, the
scene's local east-north-up frame). Each builder returns a fresh dict, so a test may change
its copy; tests/conftest.py's ``scene_file`` fixture writes one to a file."""

from __future__ import annotations

from datetime import datetime, timezone

import repo_paths
from emulator.testing.scene_toml import dumps

TX_POSITION = [20.0, 5.0, 0.0]  # transmitter 1 of the one-transmitter scenes, metres


def one_tx(rate_hz: float | None = None, channels: int | None = None) -> dict:
    """Transmitter 1 at TX_POSITION, the receiver at the origin, defaults otherwise."""
    scene: dict = {"spec": 1}
    if rate_hz is not None:
        scene["rate_hz"] = rate_hz
    scene["transmitters"] = [{"id": 1, "position": list(TX_POSITION)}]
    scene["receiver"] = {"position": [0.0, 0.0, 0.0]}
    if channels is not None:
        scene["receiver"]["channels"] = channels
    return scene


def link_faults_scene(seed: int, rate_hz: float | None = None, **faults: float) -> dict:
    """one_tx() with the link-fault effect on; ``faults`` are its ``[link_faults]`` keys
    (loss, corrupt, disconnect_every_s ...), drawn from ``seed``."""
    scene = one_tx(rate_hz)
    scene["seed"] = seed
    scene["effects"] = {"link_faults": True}
    scene["link_faults"] = dict(faults)
    return scene


def two_rx(channels_7: int | None = None) -> dict:
    """Transmitter 1 at TX_POSITION, receivers 1 at the origin and 7 at (10, 0, 0) m."""
    seven: dict = {"id": 7, "position": [10.0, 0.0, 0.0]}
    if channels_7 is not None:
        seven["channels"] = channels_7
    return {
        "spec": 1,
        "transmitters": [{"id": 1, "position": list(TX_POSITION)}],
        "receivers": [{"id": 1, "position": [0.0, 0.0, 0.0]}, seven],
    }


def vehicle_scene_text(vehicle: str, tx_position=TX_POSITION, channels: int = 2, seed: int | None = None) -> str:
    """TOML text: transmitter 1 at ``tx_position``, a receiver of ``channels`` channels
    moved by the vehicle whose ``[receiver.vehicle]`` table holds the TOML lines
    ``vehicle``. That table comes last: a test may append keys to it."""
    scene: dict = {"spec": 1}
    if seed is not None:
        scene["seed"] = seed
    scene["transmitters"] = [{"id": 1, "position": list(tx_position)}]
    scene["receiver"] = {"channels": channels}
    return dumps(scene) + f"[receiver.vehicle]\n{vehicle}\n"


def external_mavlink_text(port: int) -> str:
    """TOML text: transmitter 1 at (15, 0, 0) m, a 1-channel receiver whose pose an
    autopilot sends over MAVLink to udpin:127.0.0.1:``port`` (its local origin at
    (5, 0, 0) m of the scene); ``[receiver.vehicle]`` last, as in vehicle_scene_text."""
    return vehicle_scene_text(
        f'controller = "external_mavlink"\nmavlink = "udpin:127.0.0.1:{port}"\nmavlink_origin = [5.0, 0.0, 0.0]',
        tx_position=[15.0, 0.0, 0.0], channels=1,
    )


def default_scene_text(rate_hz: float) -> str:
    """The shipped default scene (emulator/scenes/default.toml, 1 Hz) at another rate."""
    text = (repo_paths.SCENES / "default.toml").read_text()
    assert "rate_hz = 1.0" in text
    return text.replace("rate_hz = 1.0", f"rate_hz = {rate_hz!r}")


FIELD_ORIGIN = (46.5, 8.0, 2500.0)  # lat, lon (degrees), alt (m): the field scenes' origin
FIELD_START_UTC = datetime(2026, 1, 15, 10, 0, 0, tzinfo=timezone.utc)


def field_scene(receiver: dict, ground_truth: dict, **top) -> dict:
    """Transmitter 1 buried 1 m under FIELD_ORIGIN, one receiver (``receiver``: its table,
    e.g. gps/attitude flags and a path), the ``[ground_truth]`` table given (rates ...);
    ``top`` adds top-level keys (seed, rate_hz)."""
    lat, lon, alt = FIELD_ORIGIN
    return {
        "spec": 1,
        **top,
        "origin": {"lat": lat, "lon": lon, "alt": alt},
        "ground_truth": dict(ground_truth),
        "transmitters": [{"id": 1, "position": [0.0, 0.0, -1.0]}],
        "receiver": dict(receiver),
    }
