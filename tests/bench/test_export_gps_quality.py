"""export writes the receiver GPS's logged fix quality and HDOP after the normative
columns (issue 15), and ``arva-bench fit`` reads them back, from the CSV and from the
session directory. Sessions are written directly (exact clocks, no ptys)."""

import datetime as dt

import numpy as np
import pytest

from bench.cli import main
from bench.export import COLUMNS, Track, export_rows, write_csv
from bench.fit.cli import load_input
from bench.fit.csvio import read_csv
from bench.fit.table import Table, gps_scale
from bench.session import SessionWriter
from emulator.frames.geodesy import Origin, enu_to_geodetic
from emulator.truth.nmea import gps_sentences, pashr_sentence
from firmware_proto.sentences import encode_parva

ORIGIN = Origin(46.5, 8.0, 2500.0)
START_UTC = 1768471200.0  # 2026-01-15T10:00:00Z
SECONDS = 12
#: The GGA of second k: RTK fixed, float, SBAS, plain GPS, dead reckoning, ...
QUALITY = [4, 4, 5, 2, 1, 1, 6, 2, 2, 4, 1, 5]
HDOP = [0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, None, 1.4, 1.5, 1.6, 1.7]  # None: an empty field


def _without_hdop(sentences: bytes) -> bytes:
    """The GGA's HDOP field emptied, checksum recomputed (receivers that omit it)."""
    out = []
    for line in sentences.split(b"\r\n"):
        if line[3:6] == b"GGA":
            body = line[1 : line.index(b"*")].split(b",")
            body[8] = b""
            payload = b",".join(body)
            check = 0
            for c in payload:
                check ^= c
            line = b"$" + payload + b"*%02X" % check
        out.append(line)
    return b"\r\n".join(out)


def write_session(path, arva_delay: float):
    manifest = {
        "devices": {
            "arva": {"kind": "arva", "url": "x", "role": "rx"},
            "gps-rx": {"kind": "gps", "url": "y", "role": "rx"},
            "attitude-rx": {"kind": "attitude", "url": "z", "role": "rx"},
        },
        "origin": {"lat": ORIGIN.lat, "lon": ORIGIN.lon, "alt": ORIGIN.alt},
        "tx_poses": {"1": {"lat": 46.5, "lon": 8.0, "alt": 2499.0}},
    }
    w = SessionWriter(path, manifest)
    for k in range(SECONDS):
        lat, lon, alt = (float(v) for v in enu_to_geodetic(-10.0 + k, 5.0, 1.0, ORIGIN))
        utc = dt.datetime.fromtimestamp(START_UTC + k, dt.timezone.utc)
        gga = gps_sentences(utc, lat, lon, alt, quality=QUALITY[k], hdop=HDOP[k] or 1.0, lat_lon_decimals=9)
        w.raw("gps-rx", gga if HDOP[k] is not None else _without_hdop(gga), mono=1000.0 + k, utc=START_UTC + k)
        w.raw("attitude-rx", pashr_sentence(utc, 90.0, 0.0, 0.0), mono=1000.0 + k, utc=START_UTC + k)
        w.raw("arva", encode_parva(k, 1, 1, 1, 500 + k, 0), mono=1000.0 + k + arva_delay, utc=START_UTC + k + arva_delay)
    w.close()


@pytest.mark.parametrize(
    "delay, nearest",
    [
        (0.3, list(range(SECONDS - 1))),  # 0.3 s after fix k: fix k is nearer
        (0.7, list(range(1, SECONDS))),  # 0.7 s after fix k: fix k + 1
    ],
)
def test_each_row_takes_the_nearest_receiver_fix(tmp_path, delay, nearest):
    write_session(tmp_path / "s", delay)
    out = export_rows(tmp_path / "s")
    # The last epoch arrives after the last fix (no pose): SECONDS - 1 rows.
    assert out.rows == SECONDS - 1
    assert out.columns["fix_quality"].tolist() == [QUALITY[k] for k in nearest]
    want = [np.nan if HDOP[k] is None else HDOP[k] for k in nearest]
    np.testing.assert_array_equal(out.columns["hdop"], want)


def test_nearest_fix_ties_take_the_earlier_and_ends_take_the_end():
    tr = Track(pos_t=np.array([10.0, 11.0, 12.0]), pos=np.zeros((3, 3)),
               fix_quality=np.array([4, 5, 2]), hdop=np.array([0.5, np.nan, 2.0]))  # fmt: skip
    q, h = tr.gps_quality(np.array([9.0, 10.5, 10.51, 11.5, 11.49, 13.0]))
    assert q.tolist() == [4, 4, 5, 5, 5, 2]
    np.testing.assert_array_equal(h, [0.5, 0.5, np.nan, np.nan, np.nan, 2.0])
    one = Track(pos_t=np.array([10.0]), pos=np.zeros((1, 3)), fix_quality=np.array([1]), hdop=np.array([0.9]))
    assert one.gps_quality(np.array([0.0, 20.0]))[0].tolist() == [1, 1]
    assert Track().gps_quality(np.array([1.0]))[0].tolist() == [0]


def test_csv_has_the_normative_header_then_the_gps_columns(tmp_path):
    write_session(tmp_path / "s", 0.4)
    out = export_rows(tmp_path / "s")
    write_csv(out.columns, tmp_path / "s.csv")
    lines = (tmp_path / "s.csv").read_text().splitlines()
    assert lines[0] == ",".join(COLUMNS) + ",fix_quality,hdop"
    tails = [",".join(line.split(",")[19:]) for line in lines[1:]]
    assert tails == ["4,0.60", "4,0.70", "5,0.80", "2,0.90", "1,1.00", "1,1.10", "6,1.20", "2,", "2,1.40", "4,1.50", "1,1.60"]
    # The fit reads them back: an empty HDOP is NaN and takes the others' median.
    table = read_csv(tmp_path / "s.csv")
    assert table.fix_quality.tolist() == QUALITY[:-1]
    np.testing.assert_array_equal(table.hdop, [np.nan if h is None else h for h in HDOP[:-1]])
    # sigma per row: quality sigma (RTK 0.02, float 0.3, SBAS 0.5, GPS 1.5, DR 3) x HDOP;
    # row 7 takes the median of the other HDOPs, 1.05; all relative to the median row,
    # which is row 7 itself (SBAS x 1.05 = 0.525).
    sig = np.array([0.012, 0.014, 0.24, 0.45, 1.5, 1.65, 3.6, 0.525, 0.7, 0.03, 2.4])
    np.testing.assert_allclose(gps_scale(table), sig / 0.525, rtol=1e-12)


def test_fit_of_a_session_uses_the_logged_gps_quality(tmp_path):
    write_session(tmp_path / "s", 0.4)
    table = load_input(str(tmp_path / "s"))
    assert table.fix_quality.tolist() == QUALITY[:-1]
    np.testing.assert_array_equal(table.hdop, [np.nan if h is None else h for h in HDOP[:-1]])


def test_exported_csv_and_session_fit_the_same(tmp_path, capsys):
    """`fit SESSION` and `fit CSV` of its export agree (the GPS columns travel through the CSV)."""
    write_session(tmp_path / "s", 0.4)
    assert main(["export", str(tmp_path / "s"), "--csv", str(tmp_path / "s.csv")]) == 0
    capsys.readouterr()
    a = load_input(str(tmp_path / "s"))
    b = read_csv(tmp_path / "s.csv")
    np.testing.assert_array_equal(a.fix_quality, b.fix_quality)
    np.testing.assert_array_equal(a.hdop, b.hdop)
    np.testing.assert_allclose(gps_scale(a), gps_scale(b), rtol=1e-12)


def test_fit_says_it_used_the_gps_quality():
    """The fit of a table with the GPS columns scales each row's GPS error and says so."""
    from fit_campaign import PoseError, emulate_campaign

    from bench.fit import FitOptions, fit_table
    from bench.fit.likelihood import Params
    from emulator.receiver.model import ModelParams

    table = emulate_campaign(5, ModelParams(kappa_eq=1.542, r_en=80.0), seed=3, pose_error=PoseError(gps_h=0.5, gps_v=0.75))
    opts = FitOptions(free=("kappa_eq", "r_en"), base=Params(gps_sigma=0.5, attitude_sigma=1e-3))
    assert not any("fix quality" in n for n in fit_table(table, opts).notes)
    table.fix_quality = np.where(np.arange(len(table)) % 2 == 0, 2, 4)
    table.hdop = np.full(len(table), 0.9)
    notes = fit_table(table, opts).notes
    assert "each row's GPS error follows its logged fix quality and HDOP (gps_sigma is the median row's)" in notes


def test_a_session_without_any_gps_fix_scales_nothing():
    """A fixed, surveyed receiver pose exports quality 0 on every row: that must not mark
    every row as "no fix" (a factor 1e3, which would drop them all from the fit)."""
    table = Table.from_mapping(
        "t.csv",
        {c: np.zeros(3) for c in COLUMNS} | {"fix_quality": np.zeros(3, dtype=np.int64), "hdop": np.full(3, np.nan)},
    )
    assert gps_scale(table) is None
    table.fix_quality = np.array([0, 1, 1])
    table.hdop = np.array([np.nan, 1.0, 2.0])
    assert gps_scale(table).tolist() == [1e3, 1.5 * 1.0 / 2.25, 1.5 * 2.0 / 2.25]
