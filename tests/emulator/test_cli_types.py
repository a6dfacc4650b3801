"""emulator.cli_types: each command-line type's range and its one-line reason, exactly."""

from __future__ import annotations

import argparse

import pytest

from emulator import cli_types as ct
from firmware_proto.errors import InputError, LinkError, SceneError


def refuses(parse, text: str) -> str:
    with pytest.raises(argparse.ArgumentTypeError) as info:
        parse(text)
    return str(info.value)


def test_reals_are_finite_and_in_range():
    r = ct.real(0.0, 10.0, lo_open=True)
    assert r("10") == 10.0 and r("1e-300") == 1e-300
    assert refuses(r, "0") == "must be > 0, got 0"
    assert refuses(r, "10.5") == "must be <= 10, got 10.5"
    for text in ("nan", "inf", "-inf", "1e309"):
        assert refuses(r, text) == f"expected a finite number, got {text!r}"
    assert refuses(r, "x") == "expected a number, got 'x'"
    assert refuses(r, "") == "expected a number, got ''"


def test_speed_seconds_and_integers():
    assert ct.speed("0") == 0.0 and ct.speed("1e6") == 1e6
    assert refuses(ct.speed, "1e-308") == "must be 0 (as fast as possible) or within 1e-06..1e+06, got 1e-308"
    assert ct.seconds("0") == 0.0
    assert refuses(ct.seconds, "1e308") == "must be <= 3.1536e+07, got 1e308"
    assert refuses(ct.positive_seconds, "0") == "must be > 0, got 0"
    assert ct.positive_int("7") == 7
    assert refuses(ct.positive_int, "0") == "must be >= 1, got 0"
    assert refuses(ct.positive_int, "1.5") == "expected a whole number, got '1.5'"
    assert refuses(ct.positive_int, "\u0661") == "expected a whole number, got '\u0661'"  # Arabic-Indic one
    assert refuses(ct.seed, "-1") == "must be >= 0, got -1"
    assert refuses(ct.seed, str(2**63)) == f"must be <= {2**63 - 1}, got {2**63}"
    assert ct.baud_rate("115200") == 115200
    assert refuses(ct.baud_rate, "49") == "must be within 50..12000000, got 49"


def test_lists_choices_and_addresses():
    area = ct.real_list(2, 2, 0.0, 100.0, lo_open=True, what="--area")
    assert area("1,2.5") == (1.0, 2.5)
    assert refuses(area, "1") == "--area: expected 2 comma-separated numbers, got '1'"
    assert refuses(area, "1,nan") == "--area: expected a finite number, got 'nan'"
    names = ct.choice_list(("a", "b"), "strategy")
    assert names("b,a") == ("b", "a")
    assert refuses(names, "") == "unknown strategy '' (choose from a, b)"
    assert refuses(names, "a,a") == "a strategy is repeated in 'a,a'"
    assert ct.scheduler_address("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    assert refuses(ct.scheduler_address, "http://x:1") == "unknown scheme 'http' in 'http://x:1' (tcp, tls, ucx, ws or wss)"
    assert refuses(ct.scheduler_address, "host:99999").startswith("expected [SCHEME://]HOST:PORT")


def test_geodetic_values():
    assert ct.origin("46.5,8,2500") == [46.5, 8.0, 2500.0]
    assert refuses(ct.origin, "91,0") == "--origin: latitude must be within -90..90 degrees, got 91"
    assert refuses(ct.origin, "0,0,1e9") == "--origin: altitude must be within -12000..100000 m, got 1e+09"
    assert ct.tx_pose("65535=1,2,3,90,0,0") == (65535, [1.0, 2.0, 3.0, 90.0, 0.0, 0.0])
    assert refuses(ct.tx_pose, "65536=1,2,3") == "expected ID=lat,lon,alt[,heading,roll,pitch] with ID 0..65535, got '65536=1,2,3'"
    assert refuses(ct.tx_pose, "1=1,2") == "--tx-pose 1: expected 3..6 comma-separated numbers, got '1,2'"


def test_paths(tmp_path):
    f = tmp_path / "f.txt"
    f.write_text("x")
    assert ct.input_file(str(f)) == f
    assert refuses(ct.input_file, "") == "expected a path, got ''"
    assert refuses(ct.input_file, str(tmp_path)) == f"{tmp_path}: is a directory, expected a file"
    assert refuses(ct.input_file, str(tmp_path / "no")) == f"{tmp_path / 'no'}: no such file"
    out = ct.output_file((".csv",))
    assert out(str(tmp_path / "o.csv")) == tmp_path / "o.csv"
    assert refuses(out, str(tmp_path / "o.txt")) == f"{tmp_path / 'o.txt'}: expected a .csv file"
    assert refuses(out, str(tmp_path / "no" / "o.csv")) == f"{tmp_path / 'no' / 'o.csv'}: directory {tmp_path / 'no'} does not exist"
    assert ct.output_dir(str(tmp_path / "a" / "b")) == tmp_path / "a" / "b"  # creatable
    assert refuses(ct.output_dir, str(f)) == f"{f}: exists and is not a directory"
    assert refuses(ct.output_dir, str(f / "sub")) == f"{f / 'sub'}: {f} is not a directory"
    with pytest.raises(InputError, match="cannot write"):
        ct.probe_writable(tmp_path / "no" / "x.csv", "--out")
    ct.probe_writable(tmp_path / "x.csv", "--out")
    assert not (tmp_path / "x.csv").exists()  # the probe leaves nothing behind


def test_device_spec():
    gps = ct.device_spec("gps", ("nmea",))
    assert gps("/dev/ttyUSB0,role=tx3,format=nmea") == ("/dev/ttyUSB0", "tx3", "nmea")
    arva = ct.device_spec("arva")
    assert arva("socket://h:1,role=rx2") == ("socket://h:1", "rx2")
    assert refuses(arva, ",role=rx") == "',role=rx': no device URL before the options"
    assert refuses(arva, "x,format=nmea") == "'x,format=nmea': arva devices take no format option, got 'nmea'"


def test_one_line_parser_keeps_help(capsys):
    p = ct.OneLineParser(prog="tool")
    p.add_argument("--n", type=ct.positive_int)
    with pytest.raises(SystemExit) as info:
        p.parse_args(["--n", "0"])
    assert info.value.code == 2
    assert capsys.readouterr().err == "tool: error: argument --n: must be >= 1, got 0\n"
    with pytest.raises(SystemExit) as info:
        p.parse_args(["--help"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("usage: tool [-h] [--n N]")


@pytest.mark.parametrize(
    "exc, code, line",
    [
        (InputError("a\nb"), 2, "tool: a; b\n"),
        (SceneError("s.toml", "model.r_en", "must be > 0"), 2, "tool: s.toml: model.r_en: must be > 0\n"),
        (LinkError("port /dev/x: gone"), 2, "tool: port /dev/x: gone\n"),
        (PermissionError(13, "Permission denied", "/root/x"), 2, "tool: /root/x: Permission denied\n"),
        (FileNotFoundError(2, "No such file or directory", "/dev/pts/1", None, "/proc/l"), 2,
         "tool: /dev/pts/1 -> /proc/l: No such file or directory\n"),
        (KeyboardInterrupt(), 130, "tool: interrupted\n"),
    ],
)
def test_run_main_maps_expected_errors_to_one_line(exc, code, line, capsys):
    def run(_args):
        raise exc

    assert ct.run_main("tool", lambda: argparse.Namespace(), run) == code
    assert capsys.readouterr().err == line


def test_run_main_leaves_bugs_their_traceback():
    def run(_args):
        raise ZeroDivisionError

    with pytest.raises(ZeroDivisionError):
        ct.run_main("tool", lambda: argparse.Namespace(), run)


def test_one_line():
    assert ct.one_line("x\n\n  y  \n") == "x; y"


def test_a_path_part_longer_than_name_max_is_an_argument_error():
    with pytest.raises(argparse.ArgumentTypeError, match=r"^aaaaaaaaaaaaaaaa\.\.\.: a path part longer than 255 bytes \(256\)$"):
        ct.output_dir("/tmp/" + "a" * 256)
    with pytest.raises(argparse.ArgumentTypeError, match=r"a path longer than 4095 bytes \(4351\)$"):
        ct.input_file("/".join(["b" * 255] * 17))
    assert ct.output_dir("/tmp/" + "a" * 255) is not None  # at the limit: fine (not created)


def test_an_os_error_while_parsing_is_one_line(capsys):
    def parse():
        raise PermissionError(13, "Permission denied", "/root/x")

    assert ct.run_main("prog", parse, lambda args: 0) == 2
    assert capsys.readouterr().err == "prog: /root/x: Permission denied\n"
