"""Streaming ground-truth readers: exact records, counted rejects, bounded memory, and
generator -> reader round trips."""

from __future__ import annotations

import math
from datetime import date, datetime, time, timedelta, timezone
from functools import reduce

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bench.ground_truth import (
    Attitude,
    AttitudeReader,
    DayTracker,
    GpsFix,
    GpsReader,
    GroundTruthReader,
    LineSplitter,
)
from emulator.frames.attitude import hpr_to_quaternion
from emulator.truth.nmea import (
    gga_sentence,
    gps_sentences,
    pashr_from_quaternion,
    pashr_sentence,
    rmc_sentence,
)
from emulator.frames.rotation import quaternion_matrices

UTC = timezone.utc


def s(body: str) -> bytes:
    """``$body*hh\\r\\n`` with a correct checksum computed here."""
    cs = reduce(lambda a, c: a ^ ord(c), body, 0)
    return f"${body}*{cs:02X}\r\n".encode()


GGA = "GPGGA,123519.00,4807.0380000,N,01131.0000000,E,1,08,0.9,545.4,M,46.9,M,,"
RMC = "GPRMC,123519.00,A,4807.0380000,N,01131.0000000,E,022.4,084.4,230394,003.1,W,A"
PASHR = "PASHR,204132.040,010.99,T,+00.41,-00.75,-00.84,0.151,0.088,0.569,1,0"


def feed_all(reader, data: bytes, chunk: int = 0):
    if chunk <= 0:
        return reader.feed(data) + reader.flush()
    out = []
    for i in range(0, len(data), chunk):
        out += reader.feed(data[i : i + chunk])
    return out + reader.flush()


# ---------------------------------------------------------------------------- lines


@pytest.mark.parametrize("eol", [b"\r\n", b"\n", b"\r"])
def test_splitter_accepts_any_line_end(eol):
    sp = LineSplitter()
    assert sp.feed(b"$A,1*00" + eol + b"$B,2*00" + eol) == [b"$A,1*00", b"$B,2*00"]
    assert sp.pending == 0


def test_splitter_holds_a_partial_line_until_it_ends():
    sp = LineSplitter()
    assert sp.feed(b"junk$GPGGA,1") == []
    assert sp.pending == len(b"$GPGGA,1")
    assert sp.feed(b"2*00\r\n") == [b"$GPGGA,12*00"]
    assert sp.stats["junk_bytes"] == 4


def test_splitter_resyncs_on_dollar_and_counts():
    sp = LineSplitter()
    lines = sp.feed(b"$GPGGA,123519,48$GPRMC,x*00\r\n\xb5b\x01\x07\x00\x00\r\n$OK*00\n")
    assert lines == [b"$GPRMC,x*00", b"$OK*00"]
    assert sp.stats["fragments"] == 1
    assert sp.stats["junk_bytes"] == len(b"$GPGGA,123519,48") + 6
    assert sp.stats["lines"] == 2


def test_splitter_drops_overlong_lines_and_keeps_memory_bounded():
    sp = LineSplitter(max_line=32)
    assert sp.feed(b"$" + b"A" * 100) == []
    assert sp.pending == 0 and sp.stats["overlong"] == 1
    assert sp.feed(b"B" * 1000 + b"\r\n$GOOD*00\r\n") == [b"$GOOD*00"]
    assert sp.feed(b"$" + b"C" * 40 + b"\r\n") == []
    assert sp.stats["overlong"] == 2
    # A line may be exactly max_line long.
    assert sp.feed(b"$" + b"D" * 31 + b"\n") == [b"$" + b"D" * 31]
    # A long '$' run inside binary resumes at its next '$'.
    assert sp.feed(b"$" + b"\x00" * 40 + b"$X*00\n") == [b"$X*00"]


def test_splitter_flush_and_byte_count():
    sp = LineSplitter()
    assert sp.feed(b"$A*00\r\n$B*0") == [b"$A*00"]
    assert sp.flush() == [b"$B*0"]
    assert sp.flush() == []
    assert sp.stats["bytes"] == 11


# ---------------------------------------------------------------------------- GPS


def test_gga_then_rmc_exact_records():
    r = GpsReader()
    gga, rmc = feed_all(r, s(GGA) + s(RMC))
    # GGA before any date: time of day only.
    assert gga == GpsFix(
        sentence="GGA", talker="GP", time_of_day=time(12, 35, 19), utc=None,
        lat=round(48 + 7.038 / 60, 10), lon=round(11 + 31 / 60, 10), alt_msl=545.4, geoid_sep=46.9, alt_hae=545.4 + 46.9,
        quality=1, sats=8, hdop=0.9,
    )  # fmt: skip
    assert gga.lat == pytest.approx(48.1173, abs=1e-12)
    assert rmc.utc == datetime(1994, 3, 23, 12, 35, 19, tzinfo=UTC)
    assert (rmc.status, rmc.mode, rmc.speed_knots, rmc.course) == ("A", "A", 22.4, 84.4)
    assert (rmc.alt_msl, rmc.quality) == (None, None)
    assert gga.valid and rmc.valid
    assert dict(r.stats) | {"bytes": 0} == {
        "bytes": 0, "lines": 2, "gga": 1, "rmc": 1, "fixes": 2,
    }  # fmt: skip


def test_gga_after_rmc_is_dated():
    r = GpsReader()
    fixes = feed_all(r, s(RMC) + s(GGA.replace("123519.00", "123520.00")))
    assert fixes[1].utc == datetime(1994, 3, 23, 12, 35, 20, tzinfo=UTC)


def test_midnight_rollover_gga_before_the_new_rmc():
    r = GpsReader()
    stream = (
        s("GPRMC,235959.50,A,4807.038,N,01131.000,E,0.0,,311299,,,A")
        + s("GPGGA,235959.90,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
        + s("GPGGA,000000.10,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")  # before the RMC of 1 Jan
        + s("GPRMC,000000.10,A,4807.038,N,01131.000,E,0.0,,010100,,,A")
        + s("GPGGA,000001.10,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
    )
    utcs = [f.utc for f in feed_all(r, stream)]
    assert utcs == [
        datetime(1999, 12, 31, 23, 59, 59, 500000, tzinfo=UTC),
        datetime(1999, 12, 31, 23, 59, 59, 900000, tzinfo=UTC),
        datetime(2000, 1, 1, 0, 0, 0, 100000, tzinfo=UTC),
        datetime(2000, 1, 1, 0, 0, 0, 100000, tzinfo=UTC),
        datetime(2000, 1, 1, 0, 0, 1, 100000, tzinfo=UTC),
    ]


def test_day_tracker_backwards_and_start():
    t = DayTracker(datetime(2020, 1, 1, 0, 0, 5))  # naive start is UTC
    assert t.resolve(time(23, 59, 58)) == datetime(2019, 12, 31, 23, 59, 58, tzinfo=UTC)
    assert t.resolve(time(0, 0, 1)) == datetime(2020, 1, 1, 0, 0, 1, tzinfo=UTC)
    assert t.resolve(time(11, 0)) == datetime(2020, 1, 1, 11, 0, tzinfo=UTC)
    assert t.resolve(time(23, 0)) == datetime(2020, 1, 1, 23, 0, tzinfo=UTC)  # a 12 h tie goes forward
    assert t.resolve(time(1, 0)) == datetime(2020, 1, 2, 1, 0, tzinfo=UTC)
    assert DayTracker().resolve(time(1, 0)) is None
    assert t.anchor(date(2021, 5, 6), time(7, 8, 9)) == datetime(2021, 5, 6, 7, 8, 9, tzinfo=UTC)


def test_zda_dates_gga():
    r = GpsReader()
    fixes = feed_all(r, s("GPZDA,,,,,00,00") + s("GPZDA,051134.000,04,07,2012,,") + s(
        "GPGGA,051134.000,4744.6980,N,12206.7275,W,1,05,1.9,135.4,M,-17.1,M,18.8,0000"
    ))
    assert [f.utc for f in fixes] == [datetime(2012, 7, 4, 5, 11, 34, tzinfo=UTC)]
    assert fixes[0].alt_hae == pytest.approx(135.4 - 17.1, abs=1e-12)
    assert r.stats["zda"] == 2
    feed_all(r, s("GPZDA,051134.000,31,02,2012,,") + s("GPZDA,051134.000,4,07,12,,"))
    assert r.stats["malformed"] == 2


@pytest.mark.parametrize("talker", ["GP", "GN", "GL", "GA", "BD", "GB", "GQ", "GI"])
def test_any_talker(talker):
    (fix,) = feed_all(GpsReader(), s(talker + GGA[2:]))
    assert fix.talker == talker and fix.lat == pytest.approx(48.1173)


def test_rejects_are_counted_never_raised():
    bad_checksum = s(GGA)[:-4] + b"00\r\n"
    no_checksum = b"$" + GGA.encode() + b"\r\n"
    lower_hex = s(GGA).replace(s(GGA)[-4:-2], s(GGA)[-4:-2].lower())
    stream = (
        bad_checksum
        + no_checksum
        + s("GPGSV,3,1,11,03,03,111,00")  # ignored
        + b"\xb5\x62\x01\x07\x5c\x00" + bytes(range(256)) + b"\r\n"  # UBX-ish binary
        + b"$GPGGA,12\xff3519*00\r\n"  # non-ASCII
        + s(GGA.replace("123519.00", "12351.9"))  # malformed time
        + s(GGA.replace("4807.0380000,N", "4807.0380000,X"))  # bad hemisphere
        + s(GGA.replace("4807.0380000", "4860.5000000"))  # 60 minutes with a fix
        + s(GGA.replace("0.9", "zero"))  # hdop not a number
        + s(GGA.replace("0.9", "nan"))  # float() would take it; NMEA has no NaN
        + s(GGA.replace("123519.00", "235960.00"))  # leap second
        + s("GPRMC,123519.00,A,4807.038,N,01131.000,E,022.4,084.4,230394x,,,A")  # bad date
        + s("GPGGA,,,,,,0,,,,M,,M,,")  # alive, no fix: kept
        + s("GPRMC,071732.929,V,8960.0000,N,00000.0000,E,0.00,0.00,111111,,,N")  # placeholder: kept
        + lower_hex  # lower-case checksum digits are still a checksum
    )
    r = GpsReader()
    fixes = feed_all(r, stream, chunk=5)
    assert [(f.sentence, f.lat is None) for f in fixes] == [("GGA", True), ("RMC", True), ("GGA", False)]
    assert not fixes[0].valid and not fixes[1].valid and fixes[2].valid
    st_ = r.stats
    # ignored: the GSV, and the '$' (0x24) inside the binary block, which starts a "line".
    assert (st_["bad_checksum"], st_["no_checksum"], st_["ignored"], st_["non_ascii"]) == (1, 1, 2, 1)
    assert (st_["malformed"], st_["leap_second"], st_["placeholder_position"]) == (7, 1, 1)
    assert (st_["no_position"], st_["fixes"]) == (2, 3)


def test_empty_fields_are_none_and_missing_separation_gives_no_hae():
    (fix,) = feed_all(GpsReader(), s("GNGGA,001043.00,4404.14036,N,12118.85961,W,1,12,,1150.3,M,,M,,"))
    assert (fix.alt_msl, fix.geoid_sep, fix.alt_hae, fix.hdop) == (1150.3, None, None, None)
    (rmc,) = feed_all(GpsReader(), s("GPRMC,005947.00,A,3715.6616,N,12157.6709,W,0.0,0.0,080710,,"))
    assert (rmc.mode, rmc.valid) == (None, True)  # NMEA 2.0: no mode field


def test_gll_exact_records_dated_by_the_last_rmc():
    # Garmin 48 style: GGA/RMC on even seconds, an extra GLL fix on the odd one between.
    r = GpsReader()
    stream = (s("GPGLL,4807.0380,N,01131.0000,E,123518,A")  # NMEA 2.0: no mode field; no date yet
              + s(RMC) + s("GPGLL,4807.0390,N,01131.0010,E,123520.00,A,D")
              + s("GNGLL,,,,,123521.00,V,N")  # alive, no fix
              + s("GPGLL,8960.0000,N,00000.0000,E,123522.00,V,N"))  # placeholder: kept, no position
    first, _, gll, empty, placeholder = feed_all(r, stream)
    assert first == GpsFix(
        sentence="GLL", talker="GP", time_of_day=time(12, 35, 18), utc=None,
        lat=round(48 + 7.038 / 60, 10), lon=round(11 + 31 / 60, 10), status="A",
    )  # fmt: skip
    assert first.valid and (first.mode, first.alt_hae, first.quality) == (None, None, None)
    assert gll.utc == datetime(1994, 3, 23, 12, 35, 20, tzinfo=UTC)
    assert (gll.lat, gll.lon, gll.mode, gll.valid) == (round(48 + 7.039 / 60, 10), round(11 + 31.001 / 60, 10), "D", True)
    assert (empty.talker, empty.lat, empty.status, empty.mode, empty.valid) == ("GN", None, "V", "N", False)
    assert (placeholder.lat, placeholder.valid) == (None, False)
    assert (r.stats["gll"], r.stats["rmc"], r.stats["fixes"], r.stats["no_position"]) == (4, 1, 5, 2)
    assert r.stats["placeholder_position"] == 1


def test_gll_rejects():
    r = GpsReader()
    stream = (s("GPGLL,4807.0380,N,01131.0000,E,12351,A,A")  # malformed time
              + s("GPGLL,4860.0000,N,01131.0000,E,123519,A,A")  # 60 minutes with a fix
              + s("GPGLL,4807.0380,N,01131.0000,E,123519,A,A,X"))  # a field too many
    assert feed_all(r, stream) == []
    assert (r.stats["malformed"], r.stats.get("fixes", 0)) == (3, 0)


# ---------------------------------------------------------------------------- attitude


def test_pashr_exact_record():
    r = AttitudeReader(tracker=DayTracker(datetime(2014, 2, 19, 20, 41, 32, tzinfo=UTC)))
    (att,) = feed_all(r, s(PASHR))
    q = hpr_to_quaternion(10.99, 0.41, -0.75)
    assert att == Attitude(
        time_of_day=time(20, 41, 32, 40000), utc=datetime(2014, 2, 19, 20, 41, 32, 40000, tzinfo=UTC),
        heading=10.99, roll=0.41, pitch=-0.75, quaternion=tuple(q.tolist()), heave=-0.84,
        roll_accuracy=0.151, pitch_accuracy=0.088, heading_accuracy=0.569, gps_quality=1, ins_status=0,
    )  # fmt: skip


def test_pashr_variants_and_rejects():
    r = AttitudeReader()
    stream = (
        s("PASHR,POS,0,03,183531.00,2037.76011,N,08704.07369,W,058.48,,359.4,000.0,+000.0,2.2,2.2,0.0,1.0,BQ00")
        + s("PASHR,SAT,03,28,139,38,46,U")
        + s("PASHR,,")
        + s("PASHR,204132.040,,T,+00.41,-00.75,-00.84,0.151,0.088,0.569,1,0")  # no heading
        + s("PASHR,204132.040,010.99,T,+00.41,-95.00,-00.84,0.151,0.088,0.569,1,0")  # pitch out of range
        + s("PASHR,204132.040,010.99,T,1e3,-00.75,,,,,,")  # not a plain number
        + s("PASHR,204132.040,010.99,T,+00.41,-00.75,,,,,,,")  # one field too many
        + s(GGA)
        + s("PASHR,204132.040,010.99,T,+00.41,-00.75")  # short: optional fields absent
    )
    (att,) = feed_all(r, stream, chunk=3)
    assert (att.heading, att.heave, att.gps_quality, att.utc) == (10.99, None, None, None)
    assert (r.stats["ignored"], r.stats["malformed"], r.stats["attitudes"]) == (4, 4, 1)


def test_combined_reader_dates_attitudes_from_rmc():
    r = GroundTruthReader()
    recs = feed_all(r, s(PASHR) + s(RMC) + s(PASHR.replace("204132.040", "123519.50")) + s(GGA))
    assert [type(x).__name__ for x in recs] == ["Attitude", "GpsFix", "Attitude", "GpsFix"]
    assert recs[0].utc is None
    assert recs[2].utc == datetime(1994, 3, 23, 12, 35, 19, 500000, tzinfo=UTC)
    assert recs[3].utc == datetime(1994, 3, 23, 12, 35, 19, tzinfo=UTC)
    assert (r.stats["fixes"], r.stats["attitudes"], r.stats["lines"]) == (2, 2, 4)


# ---------------------------------------------------------------------------- properties

readers = st.sampled_from([GpsReader, AttitudeReader, GroundTruthReader])
nmea_alphabet = st.sampled_from(list(b"$GPGARMCSHPZD,.*0123456789ABCDEFNSEWT+-\r\n\x00\xb5"))
noise = st.one_of(st.binary(max_size=600), st.lists(nmea_alphabet, max_size=600).map(bytes))


@given(readers, noise, st.lists(st.integers(1, 50), min_size=1, max_size=20))
def test_arbitrary_bytes_never_raise(reader_cls, data, cuts):
    reader = reader_cls(max_line=64)
    fed, i, k = 0, 0, 0
    while i < len(data):
        n = cuts[k % len(cuts)]
        out = reader.feed(data[i : i + n])
        assert all(isinstance(x, (GpsFix, Attitude)) for x in out)
        assert reader.pending <= 64
        fed += len(data[i : i + n])
        i += n
        k += 1
    reader.flush()
    assert reader.stats["bytes"] == fed == len(data)


@given(readers, st.integers(0, 10**6), st.binary(min_size=1, max_size=3), st.integers(1, 40))
def test_corrupted_valid_stream_never_raises(reader_cls, pos, junk, chunk):
    clean = s(GGA) + s(RMC) + s(PASHR) + s("GPZDA,051134.000,04,07,2012,,") + s("GPGLL,4807.038,N,01131.000,E,123520,A,A")
    at = pos % len(clean)
    data = clean[:at] + junk + clean[at + 1 :]
    reader = reader_cls()
    recs = feed_all(reader, data, chunk)
    assert len(recs) <= 4


instants = st.datetimes(datetime(2000, 1, 1), datetime(2068, 12, 31), timezones=st.just(UTC))
latitudes = st.floats(-90.0, 90.0)
longitudes = st.floats(-180.0, 180.0)


def rounded(t: datetime, unit_us: int) -> datetime:
    us = (t.microsecond + unit_us // 2) // unit_us * unit_us
    return t.replace(microsecond=0) + timedelta(microseconds=us)


@given(
    instants, latitudes, longitudes, st.floats(-500.0, 9000.0), st.floats(-110.0, 90.0),
    st.integers(0, 8), st.integers(0, 99), st.floats(0.0, 99.0), st.sampled_from(["GP", "GN", "GA", "BD"]),
    st.integers(1, 8),
)  # fmt: skip
def test_gga_round_trip(t, lat, lon, alt, sep, quality, sats, hdop, talker, decimals):
    reader = GpsReader(tracker=DayTracker(t))
    raw = gga_sentence(
        t, lat, lon, alt, geoid_sep=sep, quality=quality, sats=sats, hdop=hdop, talker=talker,
        lat_lon_decimals=decimals,
    )  # fmt: skip
    (fix,) = reader.feed(raw)
    half_unit = 0.5 / 60.0 / 10**decimals + 1e-10  # half the last printed digit, + pynmeagps's rounding
    assert abs(fix.lat - lat) <= half_unit
    assert abs((fix.lon - lon + 180.0) % 360.0 - 180.0) <= half_unit
    assert fix.utc == rounded(t, 10_000) and fix.talker == talker
    assert fix.alt_msl == round(alt - sep, 3) and fix.geoid_sep == round(sep, 3)
    assert abs(fix.alt_hae - alt) <= 1e-3 + 1e-9
    assert (fix.quality, fix.sats, fix.hdop) == (quality, sats, round(hdop, 2))


@given(instants, latitudes, longitudes, st.floats(-30.0, 30.0), st.floats(-30.0, 30.0))
def test_rmc_round_trip(t, lat, lon, ve, vn):
    (fix,) = GpsReader().feed(rmc_sentence(t, lat, lon, velocity_enu=(ve, vn, 0.0)))
    assert fix.utc == rounded(t, 10_000)
    assert abs(fix.lat - lat) <= 0.5e-7 / 60 + 1e-10
    knots = math.hypot(ve, vn) * 3600.0 / 1852.0
    assert abs(fix.speed_knots - knots) <= 0.0005 + 1e-12
    if knots == 0.0:
        assert fix.course is None
    else:
        course = math.degrees(math.atan2(ve, vn)) % 360.0
        assert abs((fix.course - course + 180.0) % 360.0 - 180.0) <= 0.005 + 1e-9
        assert 0.0 <= fix.course < 360.0


@given(
    instants,
    st.floats(-720.0, 720.0),
    st.floats(-180.0, 180.0),
    st.floats(-90.0, 90.0),
    st.floats(-99.0, 99.0),
    st.none() | st.floats(0.0, 99.0),
    st.integers(0, 2),
    st.integers(0, 1),
)
def test_pashr_round_trip(t, heading, roll, pitch, heave, acc, quality, ins):
    reader = AttitudeReader(tracker=DayTracker(t))
    raw = pashr_sentence(
        t, heading, roll, pitch, heave=heave, roll_accuracy=acc, pitch_accuracy=acc, heading_accuracy=acc,
        gps_quality=quality, ins_status=ins,
    )  # fmt: skip
    (att,) = reader.feed(raw)
    assert att.utc == rounded(t, 1_000)
    assert abs((att.heading - heading + 180.0) % 360.0 - 180.0) <= 0.005 + 1e-9
    assert 0.0 <= att.heading < 360.0
    assert (att.roll, att.pitch, att.heave) == (float(f"{roll:.2f}"), float(f"{pitch:.2f}"), float(f"{heave:.2f}"))
    assert att.roll_accuracy == (None if acc is None else float(f"{acc:.3f}"))
    assert (att.gps_quality, att.ins_status) == (quality, ins)


quaternions = st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
    lambda q: math.fsum(v * v for v in q) > 1e-6
)


@given(instants, quaternions)
def test_quaternion_through_pashr_within_print_precision(t, q):
    """Any orientation survives $PASHR to within the 0.01-degree printing: three angles
    each rounded by <= 0.005 deg move the rotation by <= 0.015 deg, gimbal lock or not."""
    (att,) = AttitudeReader().feed(pashr_from_quaternion(t, q))
    r1 = quaternion_matrices(np.asarray(q) / np.linalg.norm(q))
    r2 = quaternion_matrices(np.asarray(att.quaternion))
    cos_angle = (np.trace(r1.T @ r2) - 1.0) / 2.0
    assert math.degrees(math.acos(min(1.0, cos_angle))) <= 0.015 + 1e-6


@given(instants, latitudes, longitudes, st.floats(-100.0, 5000.0))
def test_gps_sentences_give_two_matching_records(t, lat, lon, alt):
    rmc, gga = GpsReader().feed(gps_sentences(t, lat, lon, alt))
    assert (rmc.sentence, gga.sentence) == ("RMC", "GGA")
    assert (gga.utc, gga.lat, gga.lon) == (rmc.utc, rmc.lat, rmc.lon)
    assert gga.valid and rmc.valid


# decimals >= 1 as for GGA: NMEA prints llll.ll, and pynmeagps leaves "4807" (no point) untyped.
@given(instants, latitudes, longitudes, st.sampled_from(["A", "D", "N", ""]), st.integers(1, 8))
def test_gll_round_trip(t, lat, lon, mode, decimals):
    from emulator.truth.nmea import _position  # the generator's own lat/lon formatting

    r = GpsReader()
    feed_all(r, s(f"GPZDA,{t:%H%M%S},{t:%d},{t:%m},{t:%Y},,"))  # the date comes from elsewhere
    status = "V" if mode == "N" else "A"
    (fix,) = feed_all(r, s(",".join(["GPGLL", *_position(lat, lon, decimals), f"{t:%H%M%S}.00", status, mode])))
    assert fix.utc == t.replace(microsecond=0) and fix.sentence == "GLL"
    assert fix.valid == (mode != "N")
    if mode == "N":
        return  # a no-fix sentence may carry any position
    half_unit = 0.5 / 60.0 / 10**decimals + 1e-10  # rounding to the printed arc-minutes, plus pynmeagps's 1e-10
    assert abs(fix.lat - lat) <= half_unit and abs(fix.lon - lon) <= half_unit
