"""Scenes (BRIEF 5): the typed scene and its strict TOML reader.

Errors name ``FILE: key.path: reason``. Example scenes ship in ``emulator/scenes/`` (data)."""
