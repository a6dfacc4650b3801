"""Shared by the benchmark scripts: print a table and write it into docs/performance.md.

Each script owns one section of that file, between ``<!-- BEGIN name -->`` and
``<!-- END name -->`` markers, so scripts can be re-run independently.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PERFORMANCE_MD = ROOT / "docs" / "performance.md"

_HEADER = """# Performance

Every number here was measured by the script named in its section, on the machine and
date it states. Re-run a script to refresh its section; the others stay as they are.
"""


def machine() -> str:
    """One line naming the CPU, core count and Python of this machine."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def markdown_table(header: list[str], rows: list[list[object]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def publish(name: str, title: str, body: str, script: str, write: bool = True) -> None:
    """Print ``body``; unless ``write`` is false (``--no-write``), also make it section
    ``name`` of docs/performance.md (:func:`write_section`)."""
    print(body)
    if write:
        write_section(name, title, body, script)


def write_section(name: str, title: str, body: str, script: str) -> None:
    """Replace (or append) section ``name`` of docs/performance.md."""
    today = _dt.date.today().isoformat()
    block = (
        f"<!-- BEGIN {name} -->\n## {title}\n\n"
        f"Measured {today} on {machine()} by `{script}`.\n\n{body.strip()}\n"
        f"<!-- END {name} -->\n"
    )
    replace_section(PERFORMANCE_MD, name, block, header=_HEADER)


def stamped_block(name: str, body: str, script: str, verb: str = "Measured") -> str:
    """``body`` between the markers of section ``name``, closed by a line stamping the date,
    machine, commit and ``script`` (the docs/accuracy.md and docs/model.md sections)."""
    return (
        f"<!-- BEGIN {name} -->\n{body.strip()}\n\n"
        f"_{verb} {_dt.date.today().isoformat()} on {machine()}, commit {git_revision()}, by `{script}`._\n"
        f"<!-- END {name} -->\n"
    )


def replace_section(path: Path, name: str, block: str, before: tuple[str, ...] = (), header: str = "") -> None:
    """Replace ``<!-- BEGIN name -->...<!-- END name -->`` in ``path`` by ``block``; when
    missing, insert it before the first of the sections ``before`` present, else append it
    (to ``header`` when ``path`` does not exist yet). Nothing else changes."""
    text = path.read_text() if path.exists() else header
    pattern = re.compile(rf"<!-- BEGIN {re.escape(name)} -->.*?<!-- END {re.escape(name)} -->\n?", re.S)
    later = [s for s in before if f"<!-- BEGIN {s} -->" in text]
    if pattern.search(text):
        text = pattern.sub(lambda _m: block, text)
    elif later:
        at = text.index(f"<!-- BEGIN {later[0]} -->")
        text = text[:at] + block + "\n" + text[at:]
    else:
        text = text.rstrip("\n") + "\n\n" + block
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def git_revision() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
