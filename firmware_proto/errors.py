"""The exception tree shared by all three packages.

Every error we raise on purpose derives from :class:`ArvaError`, and also from the
stdlib exception whose meaning it carries, so callers can catch either::

    ArvaError
     +-- InputError (ValueError)        bad user input: scene file, CSV, argument
     |    +-- SceneError                a scene file that does not validate
     |    +-- PoseError                 a non-finite position or degenerate quaternion
     |    +-- MissingExtra              an optional dependency (a pip extra) is not installed
     +-- ProtocolError (ValueError)     a sentence that cannot be encoded or decoded
     +-- LinkError (OSError)            a port or device that cannot be opened or used

Command lines turn :class:`InputError` and :class:`LinkError` into one line on stderr
and exit status 2; nothing else is caught, so real bugs still show a traceback.
"""

from __future__ import annotations


class ArvaError(Exception):
    """Base class of every error this project raises on purpose."""


class InputError(ArvaError, ValueError):
    """User input that cannot be used; the message names the file, key or offset."""


class SceneError(InputError):
    """A scene file that does not validate. ``str()`` is ``FILE: key.path: reason``."""

    def __init__(self, source: str, key: str, reason: str) -> None:
        self.source = source
        self.key = key
        self.reason = reason
        super().__init__(f"{source}: {key}: {reason}" if key else f"{source}: {reason}")


class PoseError(InputError):
    """A pose that cannot be used (non-finite, or a quaternion of norm < 1e-9); ``field``
    names the offending input (e.g. ``receiver.orientation``)."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}")


class MissingExtra(InputError):
    """A feature whose optional dependency (a pip extra) is not installed: an input this
    installation cannot serve, so one line and exit status 2 like any :class:`InputError`."""

    def __init__(self, feature: str, package: str, extra: str) -> None:
        self.feature = feature
        self.package = package
        self.extra = extra
        super().__init__(f"{feature} needs {package} (install the extra: pip install 'arva-bench[{extra}]')")


class ProtocolError(ArvaError, ValueError):
    """A sentence that cannot be encoded (field out of range, too long) or decoded."""


class LinkError(ArvaError, OSError):
    """A port or device that cannot be opened, written or read."""
