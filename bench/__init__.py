"""Bench: transports, ground-truth readers, session logger, replay, export, fit, dashboard."""

__version__ = "0.1.0"
