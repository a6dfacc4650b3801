"""Scenes (BRIEF 5): the scene types (``types``), the scene file's tables as schema
structs (``tables``; its TableReader also reads the vehicle table) and the scene reader
(``reader``).

Errors name ``FILE: key.path: reason``. Example scenes ship in ``emulator/scenes/`` (data)."""
