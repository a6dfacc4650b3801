"""Every option of every command, fed hostile values, in a subprocess (issue 16).

The property: whatever one option's value (nan, inf, huge, tiny, negative, empty, a path
that cannot be written, non-UTF-8 bytes ...), the command ends within a timeout with
exit status 0 or 2 (1 only where a command documents it: ``fit`` did not converge,
``cat`` lost its port mid-stream), with exactly one line on stderr when it is 2, and
never a Python traceback. ``dash`` is interactive: still running at its timeout means
it accepted its arguments and started the TUI, which is allowed (then it is killed).

Options whose *valid* values may legitimately run for a long time (``--delay 3e7``,
``--frames 1e9``, ``--t-max 86400``) are followed by a fast value of the same option:
argparse still calls the type on the hostile value (so validation is fuzzed), the
last value wins for the run.

Bounded for ``make test``: a few dozen examples, each a batch of command lines run
side by side (``BATCH``), so the whole file takes about a minute on 2 shared cores.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fit_campaign import emulate_campaign
from emulator.receiver.model import ModelParams

#: hypothesis examples, each BATCH command lines in parallel (more: ARVA_FUZZ_EXAMPLES=200)
EXAMPLES = int(os.environ.get("ARVA_FUZZ_EXAMPLES", "14"))
BATCH = 4
TIMEOUT_S = 40.0  # a command that takes longer hangs (a real run here takes < 5 s)
DASH_TIMEOUT_S = 6.0  # dash still running by then has started its TUI


@dataclass(frozen=True)
class Opt:
    """One option (``name`` None: the first positional argument). ``fast``: a value
    appended after the hostile one so that an accepted value still runs quickly."""

    name: str | None
    fast: str | None = None


@dataclass(frozen=True)
class Command:
    label: str
    argv: tuple[str, ...]  # module invocation + sub-command
    base: tuple[str, ...]  # a fast, valid invocation ({tmp}, {session}, {csv}, {cat} expanded)
    options: tuple[Opt, ...]
    codes: frozenset[int] = frozenset({0, 2})
    interactive: bool = False


EMULATE = ("-m", "emulator.cli")
BENCH = ("-m", "bench.cli")
SWEEP = ("-m", "emulator.closed_loop.sweep")

COMMANDS = (
    Command("arva-emulate", EMULATE, ("--frames", "3", "--speed", "0"), (
        Opt("--scene"), Opt("--port"), Opt("--stream"), Opt("--link"), Opt("--frames", "3"),
        Opt("--speed", "0"), Opt("--delay", "0"), Opt("--baud"), Opt("--bytesize"), Opt("--parity"),
        Opt("--stopbits"), Opt("--clock"), Opt("--control"), Opt("--capture"), Opt("--timing-log"),
    )),
    Command("cat", (*BENCH, "cat"), ("{cat}",), (
        Opt(None), Opt("--baud"), Opt("--epochs"), Opt("--until-idle", "0.2"),
    ), codes=frozenset({0, 1, 2})),
    Command("log", (*BENCH, "log"), ("--arva", "arvaemu://?speed=0&frames=5", "--out", "{new}", "--duration", "0.5"), (
        Opt("--arva"), Opt("--gps"), Opt("--attitude"), Opt("--tx-pose"), Opt("--origin"), Opt("--out"),
        Opt("--baud"), Opt("--duration", "0.5"), Opt("--note"),
    )),
    Command("export", (*BENCH, "export"), ("{session}", "--csv", "{new}.csv"), (
        Opt(None), Opt("--csv"), Opt("--origin"), Opt("--latency"), Opt("--max-gap"), Opt("--receiver"),
    )),
    Command("replay", (*BENCH, "replay"), ("{session}", "--speed", "0", "--port", "pty"), (
        Opt(None), Opt("--speed", "0"), Opt("--port"), Opt("--device"), Opt("--link"), Opt("--delay", "0"),
    )),
    Command("fit", (*BENCH, "fit"), ("{csv}",), (
        Opt(None), Opt("--report"), Opt("--write-scene"), Opt("--fit"), Opt("--r-inner"), Opt("--r-outer"),
        Opt("--q"), Opt("--pose-sigma"), Opt("--time-offset"), Opt("--seed"), Opt("--antennas"),
        Opt("--gps-sigma", "0"), Opt("--attitude-sigma", "0"), Opt("--gps-grade"), Opt("--imu-grade"), Opt("--receiver"),
    ), codes=frozenset({0, 1, 2})),
    Command("dash", (*BENCH, "dash"), (), (
        Opt(None), Opt("--gps"), Opt("--attitude"), Opt("--tx-pose"), Opt("--origin"), Opt("--baud"),
        Opt("--speed"), Opt("--stale"), Opt("--record-dir"),
    ), interactive=True),
    Command("arva-sweep", SWEEP, ("--n", "1", "--t-max", "5", "--strategies", "flux", "--workers", "1", "--area", "20,20"), (
        Opt("--n", "1"), Opt("--seed"), Opt("--strategies", "flux"), Opt("--v-max"), Opt("--k-c"),
        Opt("--area", "20,20"), Opt("--max-transmitters"), Opt("--t-max", "5"), Opt("--workers", "1"),
        Opt("--scheduler"), Opt("--out"), Opt("--antennas"), Opt("--engine"), Opt("--bootstrap", "10"),
    )),
)

SLOTS = [(c, o) for c in COMMANDS for o in c.options]

#: Values chosen to break things; strategies below add random floats, integers, text and bytes.
SPECIALS: tuple[str | bytes, ...] = (
    "nan", "-nan", "inf", "-inf", "1e308", "-1e308", "1e309", "1e-308", "-1e-308", "5e-324",
    "0", "-0", "-1", "1", "0.5", "2", "", " ", "x", ",", "1,2", "1,2,3", "nan,nan", "1e308,1e308",
    "0x10", "1_000", "99999999999999999999999", "-99999999999999999999999", "1e6", "-",
    "/", "/proc", "/proc/x", "/proc/x.csv", "/nonexistent/dir/x", "/dev/null", "{tmp}", "{tmp}/new",
    "{file}", "{session}", "bogus://x", "arvaemu://nope.toml", "arvaemu://?speed=nan",
    "role=rx", "x,role=boat", "1=nan,0,0", "1=91,0,0", "a" * 3000,
    b"\xff\xfe", b"caf\xe9", "\u00e9\u2603",
)

values = st.one_of(
    st.sampled_from(SPECIALS),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.text(max_size=12).filter(lambda s: "\0" not in s),
    st.binary(min_size=1, max_size=8).filter(lambda b: b"\0" not in b),
)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A scene-free world for the commands: a stream file, a session and a fit CSV."""
    root = tmp_path_factory.mktemp("fuzz")
    cat = root / "stream.nmea"
    cat.write_bytes(
        subprocess.run([sys.executable, *EMULATE, "--frames", "20", "--speed", "0"], capture_output=True,
                       timeout=60, check=True).stdout  # fmt: skip
    )
    session = root / "session"
    subprocess.run(
        [sys.executable, *BENCH, "log", "--arva", "arvaemu://?speed=0&frames=20", "--out", str(session), "--duration", "1"],
        capture_output=True, timeout=60, check=True,
    )
    csv = root / "walk.csv"
    emulate_campaign(20, ModelParams(kappa_eq=1.542, r_en=80.0), seed=5, n_rows=120).write_csv(csv)
    file = root / "file.txt"
    file.write_text("garbage\n")
    return {"cat": str(cat), "session": str(session), "csv": str(csv), "file": str(file), "root": root}


def _expand(value: str | bytes, names: dict[str, str]) -> bytes:
    raw = value if isinstance(value, bytes) else os.fsencode(value)
    for key, text in names.items():
        raw = raw.replace(b"{" + key.encode() + b"}", os.fsencode(text))
    return raw


#: (command, option, value) already run in this process and passed: derandomized hypothesis
#: draws the same pair again (``--scene=nan`` 7 times and ``fit --imu-grade=1095349`` 6
#: times in 56 lines, 2026-12-05), and the same command line ends the same way. A pair is
#: added only once its batch passed, so hypothesis's replay of a failing batch still runs it.
PASSED: set[tuple[str, str | None, str | bytes]] = set()


def _argv(cmd: Command, opt: Opt, value: str | bytes, names: dict[str, str]) -> list[bytes]:
    base = [_expand(a, names) for a in cmd.base]
    v = _expand(value, names)
    if opt.name is None:  # replace (or give) the positional argument
        rest = base[1:] if cmd.base and cmd.base[0].startswith("{") else base
        return [v, *rest]
    argv = [*base, opt.name.encode() + b"=" + v]
    if opt.fast is not None:
        argv += [opt.name.encode(), opt.fast.encode()]
    return argv


def _launch(cmd: Command, argv: list[bytes], cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONFAULTHANDLER": "", "TERM": "dumb", "COLUMNS": "100", "LINES": "30"}
    return subprocess.Popen(
        [os.fsencode(sys.executable), *[a.encode() for a in cmd.argv], *argv],
        cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
        start_new_session=True,
    )


def _finish(cmd: Command, proc: subprocess.Popen, what: str) -> None:
    timeout = DASH_TIMEOUT_S if cmd.interactive else TIMEOUT_S
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=10)
        assert cmd.interactive, f"{what}: still running after {timeout:g} s"
        assert b"Traceback" not in err, f"{what}: {err.decode(errors='replace')}"
        return
    text = err.decode(errors="replace")
    assert b"Traceback" not in err, f"{what}: {text}"
    assert proc.returncode in cmd.codes, f"{what}: exit {proc.returncode}: {text}"
    if proc.returncode == 2:
        assert err.endswith(b"\n") and err.count(b"\n") == 1, f"{what}: not one line on stderr: {text!r}"


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.timeout(120 + EXAMPLES * 3 * TIMEOUT_S)
@settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])  # fmt: skip
@given(st.lists(st.tuples(st.sampled_from(SLOTS), values), min_size=BATCH, max_size=BATCH))
def test_every_option_survives_hostile_values(inputs, batch):
    root: Path = inputs["root"]
    running = []
    todo = [(cmd, opt, value) for (cmd, opt), value in batch if (cmd.label, opt.name, value) not in PASSED]
    for k, (cmd, opt, value) in enumerate(todo):
        cwd = root / f"cwd-{os.getpid()}-{len(list(root.iterdir()))}-{k}"
        cwd.mkdir()
        names = {**{n: inputs[n] for n in ("cat", "session", "csv", "file")}, "tmp": str(cwd), "new": str(cwd / "out")}
        argv = _argv(cmd, opt, value, names)
        what = f"{cmd.label} {b' '.join(argv)!r}"
        running.append((cmd, _launch(cmd, argv, cwd), what))
    try:
        for cmd, proc, what in running:
            _finish(cmd, proc, what)
        PASSED.update((cmd.label, opt.name, value) for cmd, opt, value in todo)
    finally:
        # A failed assertion (or a pytest timeout) must not leave a dashboard running in
        # its own session for ever: kill whatever of this batch is still alive.
        for _, proc, _ in running:
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)


def test_every_option_is_listed():
    """The table above covers every option each parser declares (a new option must be fuzzed)."""
    from bench.cli import build_parser as bench_parser
    from emulator.cli import build_parser as emulate_parser
    from emulator.closed_loop.sweep import build_parser as sweep_parser

    def options(parser) -> set[str]:
        return {
            a.option_strings[-1] if a.option_strings[-1].startswith("--") else a.option_strings[0]
            for a in parser._actions
            if a.option_strings and a.nargs != 0 and a.dest not in ("help", "version")
        }

    declared = {"arva-emulate": options(emulate_parser()), "arva-sweep": options(sweep_parser())}
    sub = next(a for a in bench_parser()._actions if a.dest == "command")
    for name, parser in sub.choices.items():
        declared[name] = options(parser)
    listed = {c.label: {o.name for o in c.options if o.name} for c in COMMANDS}
    for label, opts in declared.items():
        if label == "devices":
            assert opts == set()  # --json only
            continue
        assert opts == listed[label], label


#: The issue's own examples (issue 16), each with its exact one-line error.
ISSUE_CASES = [
    (EMULATE, ["--speed", "1e-308"], "arva-emulate: error: argument --speed: must be 0 (as fast as possible) or within 1e-06..1e+06, got 1e-308"),
    (EMULATE, ["--delay", "1e308"], "arva-emulate: error: argument --delay: must be <= 3.1536e+07, got 1e308"),
    (EMULATE, ["--scene", ""], "arva-emulate: error: argument --scene: expected a path, got ''"),
    (EMULATE, ["--port", "pty", "--link", "/proc", "--frames", "1", "--speed", "0"], None),
    (EMULATE, ["--scene", "{scene_deep}"], "{scene_deep}: TOML nested too deeply"),
    ((*BENCH, "replay"), ["{session}", "--delay", "inf"], "arva-bench replay: error: argument --delay: expected a finite number, got 'inf'"),
    ((*BENCH, "replay"), ["{session}", "--delay", "nan"], "arva-bench replay: error: argument --delay: expected a finite number, got 'nan'"),
    ((*BENCH, "replay"), ["{session}", "--delay", "-1"], "arva-bench replay: error: argument --delay: must be >= 0, got -1"),
    ((*BENCH, "export"), ["{session}", "--csv", "o.csv", "--latency", "nan"], "arva-bench export: error: argument --latency: expected a finite number, got 'nan'"),
    ((*BENCH, "export"), ["{session}", "--csv", "o.csv", "--max-gap", "-1"], "arva-bench export: error: argument --max-gap: must be > 0, got -1"),
    ((*BENCH, "export"), ["{session}", "--csv", "/proc"], "arva-bench export: error: argument --csv: /proc: is a directory, expected a file"),
    ((*BENCH, "log"), ["--arva", "arvaemu://", "--out", "{file}", "--duration", "1"], "arva-bench log: error: argument --out: {file}: exists and is not a directory"),
    ((*BENCH, "log"), ["--arva", "arvaemu://", "--out", "/proc/x", "--duration", "1"], "arva-bench: /proc/x: cannot create: No such file or directory"),
    ((*BENCH, "fit"), ["{csv}", "--time-offset", "inf"], "arva-bench fit: error: argument --time-offset: expected a finite number, got 'inf'"),
    ((*BENCH, "fit"), ["{csv}", "--report", "{file}"], "arva-bench fit: error: argument --report: {file}: exists and is not a directory"),
    ((*BENCH, "fit"), ["{csv_delta}"], "arva-bench: fit: {csv_delta}: line 2: column delta: must be within -89..89 degrees, got 200"),
    (SWEEP, ["--t-max", "nan"], "arva-sweep: error: argument --t-max: expected a finite number, got 'nan'"),
    (SWEEP, ["--t-max", "inf"], "arva-sweep: error: argument --t-max: expected a finite number, got 'inf'"),
    (SWEEP, ["--t-max", "0"], "arva-sweep: error: argument --t-max: must be > 0, got 0"),
    (SWEEP, ["--t-max", "-1"], "arva-sweep: error: argument --t-max: must be > 0, got -1"),
    (SWEEP, ["--workers", "-1"], "arva-sweep: error: argument --workers: must be >= 1, got -1"),
    (SWEEP, ["--strategies", ""], "arva-sweep: error: argument --strategies: unknown strategy '' (choose from flux, flux_reverse, receiver_only)"),
    (SWEEP, ["--seed", "-1"], "arva-sweep: error: argument --seed: must be >= 0, got -1"),
    (SWEEP, ["--scheduler", "garbage"], "arva-sweep: error: argument --scheduler: expected [SCHEME://]HOST:PORT (e.g. tcp://10.0.0.5:8786), got 'garbage'"),
    (SWEEP, ["--area", "1e308,1e308"], "arva-sweep: error: argument --area: must be <= 10000, got 1e308"),
    (SWEEP, ["--out", "/proc/x.csv", "--n", "1"], "arva-sweep: --out /proc/x.csv: cannot write: No such file or directory"),
    # Nothing listens on port 1: a bounded wait (SCHEDULER_TIMEOUT_S), then one line.
    (SWEEP, ["--scheduler", "tcp://127.0.0.1:1", "--n", "1"], "arva-sweep: --scheduler tcp://127.0.0.1:1: cannot reach it within 10 s (..."),
]


@pytest.mark.slow
@pytest.mark.subprocess
def test_the_issues_examples_are_one_line_errors(inputs):
    root: Path = inputs["root"]
    deep = root / "deep.toml"
    deep.write_text("spec = 1\nx = " + "[" * 5000 + "]" * 5000 + "\n")
    delta = root / "delta.csv"
    lines = Path(inputs["csv"]).read_text().splitlines()
    cols = lines[1].split(",")
    cols[lines[0].split(",").index("delta")] = "200"
    delta.write_text("\n".join([lines[0], ",".join(cols), *lines[2:]]) + "\n")
    names = {**{n: inputs[n] for n in ("session", "csv", "file")}, "scene_deep": str(deep), "csv_delta": str(delta)}

    def fill(text: str) -> str:
        for key, value in names.items():
            text = text.replace("{" + key + "}", value)
        return text

    cwd = root / "issue-cases"
    cwd.mkdir(exist_ok=True)
    procs = [
        (argv, expected, subprocess.Popen([sys.executable, *module, *map(fill, argv)], cwd=cwd, stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))  # fmt: skip
        for module, argv, expected in ISSUE_CASES
    ]
    for argv, expected, proc in procs:
        _, err = proc.communicate(timeout=TIMEOUT_S)
        text = err.decode()
        assert proc.returncode == 2 and text.count("\n") == 1 and "Traceback" not in text, (argv, text)
        if expected is not None and expected.endswith("..."):  # the rest is the library's wording
            assert text.startswith(fill(expected)[:-3]), (argv, text)
        elif expected is not None:
            assert text == fill(expected) + "\n", argv


#: Issue 29, item 6: a path part longer than NAME_MAX (255 bytes) in each of the eight
#: command lines that gave an ENAMETOOLONG traceback; {long} is 300 bytes.
LONG_PART = "a" * 300
TOO_LONG = "aaaaaaaaaaaaaaaa...: a path part longer than 255 bytes"
ISSUE_29_PATHS = [
    (EMULATE, ["--scene", "{tmp}/{long}"], f"arva-emulate: error: argument --scene: {TOO_LONG} (300)"),
    (EMULATE, ["--port", "pty", "--link", "{tmp}/{long}"], f"arva-emulate: error: argument --link: {TOO_LONG} (300)"),
    ((*BENCH, "export"), ["{tmp}/{long}", "--csv", "o.csv"], f"arva-bench export: error: argument DIR: {TOO_LONG} (300)"),
    ((*BENCH, "export"), ["{session}", "--csv", "{tmp}/{long}.csv"], f"arva-bench export: error: argument --csv: {TOO_LONG} (304)"),
    ((*BENCH, "replay"), ["{tmp}/{long}"], f"arva-bench replay: error: argument DIR: {TOO_LONG} (300)"),
    ((*BENCH, "fit"), ["{csv}", "--report", "{tmp}/{long}"], f"arva-bench fit: error: argument --report: {TOO_LONG} (300)"),
    ((*BENCH, "fit"), ["{csv}", "--write-scene", "{tmp}/{long}.toml"],
     f"arva-bench fit: error: argument --write-scene: {TOO_LONG} (305)"),
    ((*BENCH, "log"), ["--arva", "arvaemu://", "--out", "{tmp}/{long}"], f"arva-bench log: error: argument --out: {TOO_LONG} (300)"),
    ((*BENCH, "fit"), ["{tmp}/{long}"], "arva-bench: {tmp}/{long}: File name too long"),
    # item 4: files that never end are not read
    (EMULATE, ["--scene", "/dev/zero"], "arva-emulate: error: argument --scene: /dev/zero: not a regular file"),
    ((*BENCH, "fit"), ["/dev/zero"],
     "arva-bench: fit: /dev/zero: a character device, not a regular file: only regular files are read as a CSV file"),
]  # fmt: skip


@pytest.mark.slow
@pytest.mark.subprocess
def test_long_path_parts_and_endless_files_are_one_line(inputs):
    root: Path = inputs["root"]
    names = {"session": inputs["session"], "csv": inputs["csv"], "tmp": str(root), "long": LONG_PART}

    def fill(text: str) -> str:
        for key, value in names.items():
            text = text.replace("{" + key + "}", value)
        return text

    procs = [
        (argv, fill(expected), subprocess.Popen([sys.executable, *module, *map(fill, argv)], cwd=root, stdin=subprocess.DEVNULL,
                                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))  # fmt: skip
        for module, argv, expected in ISSUE_29_PATHS
    ]
    for argv, expected, proc in procs:
        _, err = proc.communicate(timeout=TIMEOUT_S)
        assert (proc.returncode, err.decode()) == (2, expected + "\n"), argv


@pytest.mark.subprocess
def test_fit_outputs_that_cannot_be_written_are_refused_before_the_fit(inputs):
    """``--report /proc/x`` and ``--write-scene /proc/x.toml`` pass the permission bits as
    root; they used to fail only after the fit (its summary already printed)."""
    for argv, line in (
        (["--report", "/proc/x"], "arva-bench: fit: --report /proc/x: cannot create it in /proc: No such file or directory"),
        (["--write-scene", "/proc/x.toml"], "arva-bench: fit: --write-scene /proc/x.toml: cannot write: No such file or directory"),
    ):
        proc = subprocess.run([sys.executable, *BENCH, "fit", inputs["csv"], *argv], capture_output=True, text=True,
                              timeout=TIMEOUT_S, cwd=inputs["root"])  # fmt: skip
        assert (proc.returncode, proc.stdout, proc.stderr.count("\n")) == (2, "", 1), (argv, proc.stderr)
        if os.geteuid() == 0:  # otherwise the permission bits already refuse /proc (argparse's line)
            assert proc.stderr == line + "\n", argv
