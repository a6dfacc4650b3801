"""``arva-bench``: the bench's command line.

Each sub-command lives in its own module exposing ``register(subparsers)`` (adds its
parser) and a ``run(args) -> int`` (the parser's ``func``). ``parse_args`` is separate from
``main`` so tests can check argument handling without running anything.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from emulator.cli_types import OneLineParser, run_main

from . import __version__

#: Sub-command modules, in the order ``--help`` lists them.
SUBCOMMANDS: tuple[str, ...] = ("cat", "devices", "log", "export", "replay", "dash", "fit")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="arva-bench",
                           description="Log, replay, export and fit ARVA receivers and their ground truth.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output on stderr")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        command = importlib.import_module(f"bench.{name}")
        command.register(sub)
        sub.choices[name].set_defaults(func=command.run)
    return parser


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.error(f"a command is required: one of {', '.join(SUBCOMMANDS)} (see arva-bench --help)")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    return run_main("arva-bench", lambda: parse_args(argv), lambda args: args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
