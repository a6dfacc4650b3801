"""Reading a user's files with bounds: regular files only, and a cap on what is read.

Every file a command reads as a scene, a receiver profile, a session log or a manifest
goes through :func:`open_regular` (or :func:`read_regular`): a path that is not a regular
file after symbolic links (``/dev/zero``, a FIFO, a socket, a terminal) is refused before
it is read, since it may never end or block for ever; a file larger than the reader's cap
is refused without being read whole. Both raise :class:`FileRefused` (an
:class:`~firmware_proto.errors.InputError`: one line, exit 2) naming the path.

Caps are bytes; each reader documents its own next to the format it reads
(:data:`MAX_TOML_BYTES` here for scenes and profiles; ``bench.session`` for session files).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

from firmware_proto.errors import InputError

#: Largest scene or receiver profile (bytes). The shipped ones are a few kB; a scene
#: with a terrain or vehicle table is well under a MB.
MAX_TOML_BYTES = 16 << 20


class FileRefused(InputError):
    """A file not read: ``str()`` is ``PATH: REASON``; ``reason`` alone for readers
    that word their own errors (a scene's ``SceneError``)."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{path}: {reason}")


def _file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"),
                       (stat.S_ISFIFO, "named pipe"), (stat.S_ISSOCK, "socket")):  # fmt: skip
        if test(mode):
            return name
    return "special file"


def open_regular(path: str | Path, what: str = "file") -> BinaryIO:
    """``path`` opened for binary reading if it is a regular file (after symbolic links);
    :class:`FileRefused` otherwise (``what`` names the role in the message)."""
    try:
        st = os.stat(path)
        if stat.S_ISDIR(st.st_mode):
            raise FileRefused(path, f"a directory, not a {what}")
        if not stat.S_ISREG(st.st_mode):
            raise FileRefused(path, f"a {_file_kind(st.st_mode)}, not a regular file: only regular files are read as a {what}")
        f = open(path, "rb")
    except OSError as exc:
        raise FileRefused(path, f"cannot read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):  # replaced between the stat and the open
        f.close()
        raise FileRefused(path, f"not a regular file: only regular files are read as a {what}")
    return f


def read_regular(path: str | Path, cap: int, what: str = "file") -> bytes:
    """The whole of regular file ``path``, at most ``cap`` bytes (:class:`FileRefused`
    if it is larger: nothing beyond ``cap + 1`` bytes is read)."""
    with open_regular(path, what) as f:
        try:
            data = f.read(cap + 1)
        except OSError as exc:
            raise FileRefused(path, f"cannot read: {exc.strerror or exc}") from None
    if len(data) > cap:
        raise FileRefused(path, f"larger than {cap} bytes: not a {what}")
    return data
