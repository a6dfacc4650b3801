"""Emulator: the receiver model, scenes, effects, scheduler and ports."""

__version__ = "0.1.0"
