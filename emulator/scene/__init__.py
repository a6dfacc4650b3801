"""Scenes (BRIEF 5): the scene types (``types``), strict typed access to TOML tables
(``tables``, also used by the vehicle table's parser) and the scene reader (``reader``).

Errors name ``FILE: key.path: reason``. Example scenes ship in ``emulator/scenes/`` (data)."""
