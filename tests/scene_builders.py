"""The scenes many tests start from, built once (BRIEF 3 keys; positions in metres, the
scene's local east-north-up frame). Each builder returns a fresh dict, so a test may change
its copy; tests/conftest.py's ``scene_file`` fixture writes one to a file."""

from __future__ import annotations

from datetime import datetime, timezone

import repo_paths

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
