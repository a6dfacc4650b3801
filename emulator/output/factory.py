"""The one port factory: a port spec (``-``, ``pty``, ``rfc2217-server:...``,
``tcp-server:...``, a regular file, a serial device or pyserial URL) -> a :class:`Port`.

``arva-emulate`` (every stream) and ``arva-bench replay`` (every device) open their
ports here, so a spec means the same in both commands: the same kinds, the same
``--link DIR`` (stable symlinks ``DIR/<label>`` to the ptys, the directory created on a
fresh machine, ``:`` in a label written ``-``), the same serial settings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from firmware_proto.errors import InputError

from emulator.output.net_ports import LineSettings, ServerPort, parse_server_spec
from emulator.output.ports import FilePort, Port, PtyPort, SerialPort, StdoutPort, file_name, is_file_spec


@dataclass(frozen=True)
class PortOptions:
    """How ports are opened: UART framing and flow control for serial devices and the
    servers, ``link_dir`` for ptys, ``serve_any_host`` for servers on other than loopback,
    ``notify`` for a server's client events (one line each)."""

    line: LineSettings = field(default_factory=LineSettings)
    rtscts: bool = False
    xonxoff: bool = False
    link_dir: Path | None = None
    serve_any_host: bool = False
    notify: Callable[[str], None] | None = None

    def serial_options(self, url: str) -> dict:
        """pyserial's keyword arguments for ``url``."""
        opts = {**asdict(self.line), "rtscts": self.rtscts, "xonxoff": self.xonxoff}
        if "://" not in url:
            opts["exclusive"] = True  # a device another program holds is an error, not a fight
        return opts


def link_path(link_dir: Path | None, label: str) -> Path | None:
    """``link_dir/<label>`` (``:`` written ``-``), the directory created if missing."""
    if link_dir is None:
        return None
    try:
        link_dir.mkdir(parents=True, exist_ok=True)  # a fresh machine has no DIR yet
    except FileExistsError:
        raise InputError(f"--link {link_dir}: not a directory") from None
    except OSError as exc:
        raise InputError(f"--link {link_dir}: cannot create: {exc.strerror or exc}") from None
    return link_dir / file_name(label)


def open_port(label: str, spec: str, options: PortOptions | None = None) -> Port:
    """The port ``spec`` names, for the stream or device ``label``. Raises
    :class:`InputError` / :class:`~firmware_proto.errors.LinkError` with one line."""
    options = options or PortOptions()
    if spec == "-":
        return StdoutPort(label)
    if spec == "pty":
        return PtyPort(label, link_path(options.link_dir, label))
    server = parse_server_spec(spec)
    if server is not None:
        return ServerPort(label, server, options.line, options.serve_any_host, options.notify)
    if is_file_spec(spec):
        return FilePort(label, spec)
    return SerialPort(label, spec, options.serial_options(spec))
