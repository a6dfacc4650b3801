"""export's options on a session written directly (exact clocks, no ptys): the origin
(session, --origin, first receiver fix) and --latency."""

import numpy as np
import pytest

from bench.export import export_rows
from bench.session import SessionWriter, read_manifest
from emulator.frames.geodesy import Origin, enu_to_geodetic, geodetic_to_enu
from emulator.truth.nmea import gps_sentences, pashr_sentence
from firmware_proto.errors import InputError
from firmware_proto.sentences import encode_parva

ORIGIN = Origin(46.5, 8.0, 2500.0)
START_UTC = 1768471200.0  # 2026-01-15T10:00:00Z
SECONDS = 20


def rx_true(t):
    """The receiver walks east at 1 m/s from (-10, 5, 1)."""
    return np.array([-10.0 + t, 5.0, 1.0])


def write_truth(w, k: int) -> None:
    """Second k's GPS fix and attitude of the walker (rx), on the logger's clock."""
    import datetime as dt

    lat, lon, alt = (float(v) for v in enu_to_geodetic(*rx_true(float(k)), ORIGIN))
    utc = dt.datetime.fromtimestamp(START_UTC + k, dt.timezone.utc)
    w.raw("gps-rx", gps_sentences(utc, lat, lon, alt, lat_lon_decimals=9), mono=1000.0 + k, utc=START_UTC + k)
    w.raw("attitude-rx", pashr_sentence(utc, 90.0, 0.0, 0.0), mono=1000.0 + k, utc=START_UTC + k)


def write_session(path, origin_in_manifest: bool, arva_delay: float):
    manifest = {
        "devices": {
            "arva": {"kind": "arva", "url": "x", "role": "rx"},
            "gps-rx": {"kind": "gps", "url": "y", "role": "rx"},
            "attitude-rx": {"kind": "attitude", "url": "z", "role": "rx"},
        },
        "tx_poses": {"1": {"lat": 46.5, "lon": 8.0, "alt": 2499.0}},
    }
    if origin_in_manifest:
        manifest["origin"] = {"lat": ORIGIN.lat, "lon": ORIGIN.lon, "alt": ORIGIN.alt}
    w = SessionWriter(path, manifest)
    for k in range(SECONDS):
        write_truth(w, k)
        # The epoch measured at k arrives arva_delay seconds later (the receiver's latency).
        w.raw("arva", encode_parva(k, 1, 1, 1, 500, 0), mono=1000.0 + k + arva_delay, utc=START_UTC + k + arva_delay)
    w.close()


def rx_columns(result):
    c = result.columns
    return np.c_[c["rx_x"], c["rx_y"], c["rx_z"]]


def test_latency_moves_the_pose_lookup_back_to_the_measurement(tmp_path):
    write_session(tmp_path / "s", origin_in_manifest=True, arva_delay=0.4)
    # GPS fixes at whole seconds; epochs arrive 0.4 s late. The last epoch's arrival
    # (19.4 s) is past the last fix, so without the correction it has no pose.
    plain = export_rows(tmp_path / "s")
    assert plain.rows == SECONDS - 1 and dict(plain.dropped) == {"no receiver position": 1}
    np.testing.assert_allclose(plain.columns["rx_qw"], 1.0, atol=1e-12)  # heading 90: body x east
    truth = np.array([rx_true(k) for k in range(SECONDS)])
    # Without --latency each pose is 0.4 s (0.4 m east) ahead of where the epoch was measured.
    np.testing.assert_allclose(rx_columns(plain) - truth[:-1], [[0.4, 0.0, 0.0]] * (SECONDS - 1), atol=1e-3)
    fixed = export_rows(tmp_path / "s", latency=0.4)
    assert fixed.rows == SECONDS and not fixed.dropped
    np.testing.assert_allclose(rx_columns(fixed), truth, atol=1e-3)
    np.testing.assert_allclose(fixed.columns["t"], START_UTC + np.arange(SECONDS), atol=1e-6)


def test_origin_from_the_session_from_the_option_and_from_the_first_fix(tmp_path):
    write_session(tmp_path / "with", origin_in_manifest=True, arva_delay=0.0)
    write_session(tmp_path / "without", origin_in_manifest=False, arva_delay=0.0)
    truth = np.array([rx_true(k) for k in range(SECONDS)])

    session = export_rows(tmp_path / "with")
    assert session.origin == ORIGIN
    np.testing.assert_allclose(rx_columns(session), truth, atol=1e-3)

    # --origin overrides the session's: every position moves by the ENU offset between them.
    other = Origin(46.5001, 8.0002, 2490.0)
    moved = export_rows(tmp_path / "with", origin=[other.lat, other.lon, other.alt])
    assert moved.origin == other
    e, n, u = geodetic_to_enu(*enu_to_geodetic(truth[:, 0], truth[:, 1], truth[:, 2], ORIGIN), other)
    np.testing.assert_allclose(rx_columns(moved), np.c_[e, n, u], atol=1e-3)
    assert np.abs(rx_columns(moved) - truth).min() > 5.0  # it did move (11 m north, 15 m east, 10 m up)

    # No origin anywhere: the first receiver fix is (0, 0, 0); the walk keeps its shape.
    first = export_rows(tmp_path / "without")
    lat0, lon0, alt0 = (float(v) for v in enu_to_geodetic(*rx_true(0.0), ORIGIN))
    assert first.origin.lat == pytest.approx(lat0, abs=1e-9) and first.origin.alt == pytest.approx(alt0, abs=1e-3)
    np.testing.assert_allclose(rx_columns(first)[0], [0.0, 0.0, 0.0], atol=1e-3)
    np.testing.assert_allclose(rx_columns(first) - rx_columns(first)[0], truth - truth[0], atol=2e-3)
    assert "origin" not in read_manifest(tmp_path / "without")


def write_two_receivers(path):
    """Two receivers on one walker (rx), each its own device: d 500 and 700 cm."""
    manifest = {
        "devices": {
            "arva-a": {"kind": "arva", "url": "x", "role": "rx"},
            "arva-b": {"kind": "arva", "url": "x2", "role": "rx"},
            "gps-rx": {"kind": "gps", "url": "y", "role": "rx"},
            "attitude-rx": {"kind": "attitude", "url": "z", "role": "rx"},
        },
        "tx_poses": {"1": {"lat": 46.5, "lon": 8.0, "alt": 2499.0}},
        "origin": {"lat": ORIGIN.lat, "lon": ORIGIN.lon, "alt": ORIGIN.alt},
    }
    w = SessionWriter(path, manifest)
    for k in range(SECONDS):
        write_truth(w, k)
        w.raw("arva-a", encode_parva(k, 1, 1, 1, 500, 0), mono=1000.0 + k, utc=START_UTC + k)
        w.raw("arva-b", encode_parva(k, 1, 1, 1, 700, 0), mono=1000.0 + k, utc=START_UTC + k)
    w.close()


def test_receiver_selects_one_receivers_rows(tmp_path):
    write_two_receivers(tmp_path / "s")
    both = export_rows(tmp_path / "s")
    assert both.receivers == ("arva-a", "arva-b") and both.rows == 2 * SECONDS
    b = export_rows(tmp_path / "s", receiver="arva-b")
    assert b.receivers == ("arva-b",) and b.rows == SECONDS and set(b.columns["d"].tolist()) == {700}
    with pytest.raises(InputError, match=r": no receiver 'gps-rx' in this session \(its receivers: arva-a, arva-b\)$"):
        export_rows(tmp_path / "s", receiver="gps-rx")


def test_fit_of_a_two_receiver_session_asks_which(tmp_path, capsys):
    from bench.cli import main

    write_two_receivers(tmp_path / "s")
    assert main(["fit", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"arva-bench: fit: {tmp_path / 's'}: 2 receivers (arva-a, arva-b): the fit calibrates one; "
        "choose it with --receiver NAME\n"
    )
    # With --receiver the one receiver's 20 rows reach the fit (too few to fit: one line).
    assert main(["fit", str(tmp_path / "s"), "--receiver", "arva-a"]) == 2
    assert capsys.readouterr().err == f"arva-bench: fit: {tmp_path / 's'}: only 20 rows; the fit needs at least 50\n"
    assert main(["fit", str(tmp_path / "s") + "/manifest.json", "--receiver", "arva-a"]) == 2
    assert capsys.readouterr().err.endswith("--receiver arva-a: only for a session directory (a CSV holds one receiver's rows)\n")
