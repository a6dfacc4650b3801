"""The bench ingest: the stamp rule, export with ties, cut-invariance of the exported
table, chunked reads of every transport, keeping buffered input on reopen."""

from __future__ import annotations

import datetime as dt
import os
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import pytest

from bench.export import export_rows
from bench.ingest.reader import Device, DeviceSpec, Listener, Notifier
from bench.ingest.stamp import StampedDecoder, byte_time
from bench.records import decoder_for
from bench.session import SessionWriter
from bench.transport import open_device
from emulator.frames.geodesy import Origin, enu_to_geodetic
from emulator.truth.nmea import gps_sentences, pashr_sentence
from firmware_proto.sentences import encode_parva

ORIGIN = Origin(46.5, 8.0, 2500.0)
START_UTC = 1768471200.0  # 2026-01-15T10:00:00Z
PASHR = [pashr_sentence(dt.datetime.fromtimestamp(START_UTC + k / 10, dt.timezone.utc), 10.0 * k, 0.0, 0.0)
         for k in range(3)]  # fmt: skip


# -- the stamp rule -----------------------------------------------------------------------------
def test_records_of_one_read_are_spread_back_from_its_end_at_the_baud():
    bt = byte_time(9600)
    stamper = StampedDecoder(decoder_for("attitude"), 9600)
    data = b"".join(PASHR)
    out = stamper.feed(data, 100.0, START_UTC)
    n = len(data)
    # An NMEA line ends at its CR (the LF after it completes nothing).
    ends = [len(PASHR[0]) - 1, len(PASHR[0]) + len(PASHR[1]) - 1, n - 1]
    assert [s.mono for s in out] == [100.0 - (n - e) * bt for e in ends]
    assert [s.utc for s in out] == [START_UTC - (n - e) * bt for e in ends]
    assert [s.record["heading"] for s in out] == [0.0, 10.0, 20.0]


def test_stamps_never_go_back_a_fast_link_ties_instead():
    stamper = StampedDecoder(decoder_for("attitude"), 9600)
    first = stamper.feed(PASHR[0], 100.0, START_UTC)
    # 2 sentences 1 ms later: at 9600 Bd they would have needed ~150 ms, so they tie with the first.
    later = stamper.feed(PASHR[1] + PASHR[2], 100.001, START_UTC + 0.001)
    assert [s.mono for s in first + later] == [100.0 - byte_time(9600), 100.0 - byte_time(9600), 100.001 - byte_time(9600)]


def test_a_stop_mid_sentence_is_not_an_error_but_end_of_file_is():
    data = encode_parva(0, 1, 1, 1, 1905, 21) + b"$PARVA,1,1"
    stopped = StampedDecoder(decoder_for("arva"), 115200)
    stopped.feed(data, 1.0, 1.0)
    records, cut = stopped.stop(2.0, 2.0)
    assert cut == 10 and [r.record for r in records] == [] and stopped.decoder.stats()["errors"] == 0
    ended = StampedDecoder(decoder_for("arva"), 115200)
    ended.feed(data, 1.0, 1.0)
    assert [r.record for r in ended.flush(2.0, 2.0)] == [{"error": "TRUNCATED", "offset": len(data) - 10, "length": 10}]


# -- export: ties and cut invariance ------------------------------------------------------------
def manifest(bauds: dict[str, int]) -> dict:
    return {
        "devices": {
            "arva": {"kind": "arva", "url": "x", "role": "rx", "baudrate": bauds["arva"]},
            "gps-rx": {"kind": "gps", "url": "y", "role": "rx", "baudrate": bauds["gps-rx"]},
            "attitude-rx": {"kind": "attitude", "url": "z", "role": "rx", "baudrate": bauds["attitude-rx"]},
        },
        "origin": {"lat": ORIGIN.lat, "lon": ORIGIN.lon, "alt": ORIGIN.alt},
        "tx_poses": {"1": {"lat": 46.5001, "lon": 8.0001, "alt": 2499.0}},
    }


def test_several_attitude_sentences_in_one_read_and_repeated_stamps_export(tmp_path):
    """The field failure: one read holding several $PASHR, and reads with the same stamp."""
    w = SessionWriter(tmp_path / "s", manifest({"arva": 115200, "gps-rx": 115200, "attitude-rx": 115200}))
    for k in range(10):
        t = START_UTC + k
        lat, lon, alt = (float(v) for v in enu_to_geodetic(float(k), 0.0, 1.0, ORIGIN))
        w.raw("gps-rx", gps_sentences(dt.datetime.fromtimestamp(t, dt.timezone.utc), lat, lon, alt), 1000.0 + k, t)
        att = [pashr_sentence(dt.datetime.fromtimestamp(t + j / 4, dt.timezone.utc), 90.0 + j, 0.0, 0.0) for j in range(4)]
        w.raw("attitude-rx", b"".join(att[:3]), 1000.0 + k + 0.5, t + 0.5)  # three in one read
        w.raw("attitude-rx", att[3], 1000.0 + k + 0.5, t + 0.5)  # and a repeated stamp
        w.raw("arva", encode_parva(k, 1, 1, 1, 500, 0), 1000.0 + k + 0.5, t + 0.5)
    w.close()
    result = export_rows(tmp_path / "s")
    assert result.rows == 9 and dict(result.dropped) == {"no receiver position": 1}
    assert np.isfinite(np.c_[[result.columns[c] for c in result.columns]]).all()


BAUDS = {"arva": 115200, "gps-rx": 9600, "attitude-rx": 19200}


def device_streams() -> dict[str, list[tuple[float, bytes]]]:
    """(scheduled start s, sentence bytes) of each device over 3 s of a walk east."""
    out: dict[str, list] = {"arva": [], "gps-rx": [], "attitude-rx": []}
    for k in range(12):  # receiver: 4 Hz, two slots per epoch
        out["arva"] += [(0.3 + k / 4, encode_parva(k, 2, s, 1, 500 + 10 * k, 3 - s)) for s in (1, 2)]
    for k in range(4):  # GPS: 1 Hz GGA + RMC
        lat, lon, alt = (float(v) for v in enu_to_geodetic(1.5 * k, 0.0, 1.0, ORIGIN))
        utc = dt.datetime.fromtimestamp(START_UTC + k, dt.timezone.utc)
        out["gps-rx"].append((float(k), gps_sentences(utc, lat, lon, alt)))
    for k in range(32):  # attitude: 10 Hz, turning
        utc = dt.datetime.fromtimestamp(START_UTC + k / 10, dt.timezone.utc)
        out["attitude-rx"].append((k / 10, pashr_sentence(utc, 90.0 + 3.0 * k, 1.0, -2.0)))
    return out


def arrivals(stream: list[tuple[float, bytes]], baud: int) -> tuple[bytes, np.ndarray, list[int]]:
    """The device's bytes, each byte's arrival time at line rate, and the sentence ends."""
    bt = byte_time(baud)
    data, times, ends, free = b"", [], [], 0.0
    for start, sentence in stream:
        t = max(start, free)
        times += [t + (i + 1) * bt for i in range(len(sentence))]
        free = t + len(sentence) * bt
        data += sentence
        ends.append(len(data))
    return data, np.array(times), ends


STREAMS = {name: arrivals(s, BAUDS[name]) for name, s in device_streams().items()}


def export_cut(directory: Path, cuts: dict[str, list[int]]):
    """Session whose device reads end at ``cuts`` (byte offsets), each stamped at the
    arrival of its last byte; its exported table."""
    w = SessionWriter(directory, manifest(BAUDS))
    for name, (data, times, _) in STREAMS.items():
        start = 0
        for end in cuts[name]:
            w.raw(name, data[start:end], 1000.0 + times[end - 1], START_UTC + times[end - 1])
            start = end
    w.close()
    return export_rows(directory)


def silences(name: str) -> set[int]:
    """Offsets after which the line goes quiet: a read returns there at the latest (the
    stamp rule's premise: a read never holds bytes from both sides of a silence)."""
    _, times, _ = STREAMS[name]
    return {int(i) + 1 for i in np.flatnonzero(np.diff(times) > 1.5 * byte_time(BAUDS[name]))}


def cuts_from(sizes: list[int], name: str) -> list[int]:
    """Read ends: reads of ``sizes`` bytes (cycled), also cut wherever the line goes quiet."""
    total = len(STREAMS[name][0])
    ends, pos, i = set(silences(name)), 0, 0
    while pos < total:
        pos = min(total, pos + sizes[i % len(sizes)])
        ends.add(pos)
        i += 1
    return sorted(ends)


REFERENCE_DIR = tempfile.TemporaryDirectory()
REFERENCE = export_cut(Path(REFERENCE_DIR.name) / "s", {n: s[2] for n, s in STREAMS.items()})  # a read per sentence


def test_the_reference_export_has_every_epoch():
    # 12 epochs x 2 slots, all within the GPS's 0..3.08 s.
    assert REFERENCE.rows == 24 and dict(REFERENCE.dropped) == {}
    np.testing.assert_array_equal(REFERENCE.columns["seq"], np.repeat(np.arange(12), 2))


sizes = st.lists(st.one_of(st.integers(1, 8), st.integers(9, 120), st.integers(121, 2000)), min_size=1, max_size=12)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(arva=sizes, gps=sizes, att=sizes)
def test_the_export_is_the_same_however_the_reads_are_cut(arva, gps, att):
    cuts = {name: cuts_from(s, name) for name, s in (("arva", arva), ("gps-rx", gps), ("attitude-rx", att))}
    with tempfile.TemporaryDirectory() as tmp:
        got = export_cut(Path(tmp) / "s", cuts)
    assert got.rows == REFERENCE.rows and dict(got.dropped) == dict(REFERENCE.dropped)
    for c in ("seq", "id", "d", "delta"):
        np.testing.assert_array_equal(got.columns[c], REFERENCE.columns[c])
    # Stamps are stored to the microsecond: a record's stamp may differ by rounding alone.
    np.testing.assert_allclose(got.columns["t"], REFERENCE.columns["t"], rtol=0, atol=2e-6)
    for c in got.columns:
        if c not in ("t", "seq", "id", "d", "delta"):
            np.testing.assert_allclose(got.columns[c], REFERENCE.columns[c], rtol=0, atol=1e-4, err_msg=c)


# -- transports: chunks, reopen ------------------------------------------------------------------
class Collect(Listener):
    def __init__(self) -> None:
        self.reads: list = []
        self.links: list = []
        self.done = threading.Event()

    def on_read(self, device, read):
        if read.data:
            self.reads.append(read)

    def on_link(self, device, event):
        self.links.append(event.kind)


def wait_for(predicate, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_a_socket_is_read_in_chunks_not_bytes():
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10)
    port = server.getsockname()[1]
    data = b"".join(PASHR * 10)  # 30 sentences sent at once
    dev = Device(DeviceSpec("attitude-rx", "attitude", f"socket://127.0.0.1:{port}"))
    got = Collect()
    notifier = Notifier([dev], [got])
    notifier.start()
    try:
        conn, _ = server.accept()
        with conn:
            wait_for(lambda: got.links == ["up"])
            conn.sendall(data)
            wait_for(lambda: sum(len(r.data) for r in got.reads) == len(data))
    finally:
        notifier.stop()
        server.close()
    assert len(got.reads) == 1 and got.reads[0].data == data
    assert len(got.reads[0].records) == 30


def test_a_port_without_a_descriptor_is_read_in_chunks_by_its_thread():
    dev = Device(DeviceSpec("arva", "arva", "arvaemu://?speed=0&frames=50"))  # in-process emulator, no fd
    got = Collect()
    notifier = Notifier([dev], [got])
    notifier.start()
    try:
        wait_for(lambda: sum(len(r.records) for r in got.reads) >= 50)
    finally:
        notifier.stop()
    data = b"".join(r.data for r in got.reads)
    sentences = data.count(b"$PARVA")
    assert [s.record["seq"] for r in got.reads for s in r.records] == list(range(50))
    assert sentences == 50 * 4 and len(got.reads) < sentences  # several sentences per read


def test_a_listener_failing_on_a_tick_is_dropped_and_the_others_go_on():
    """Every listener call goes through one guard: a bug in ``on_tick`` drops that listener
    (reported through ``on_error``), it does not end the reading for the others."""

    class BrokenTick(Listener):
        def on_tick(self, mono):
            raise RuntimeError("boom")

    dev = Device(DeviceSpec("arva", "arva", "arvaemu://?speed=0&frames=50"))
    got, errors = Collect(), []
    notifier = Notifier([dev], [BrokenTick(), got], on_error=errors.append)
    notifier.start()
    try:
        wait_for(lambda: errors and sum(len(r.records) for r in got.reads) >= 50)  # a tick is every 0.1 s
    finally:
        notifier.stop()
    assert [str(e) for e in errors] == ["BrokenTick failed: RuntimeError('boom')"]
    assert [s.record["seq"] for r in got.reads for s in r.records] == list(range(50))


@pytest.mark.pty
def test_reopening_keeps_what_the_os_buffered():
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        first = open_device(path, keep_input=True)
        first.close()
        os.write(master, b"$PARVA,buffered during the outage\r\n")
        time.sleep(0.05)
        kept = open_device(path, keep_input=True, timeout=1.0)
        assert kept.read(35) == b"$PARVA,buffered during the outage\r\n"
        kept.close()
        os.write(master, b"dropped\r\n")
        time.sleep(0.05)
        flushed = open_device(path, timeout=0.2)  # pyserial's default open flushes input
        assert flushed.read(9) == b""
        flushed.close()
    finally:
        os.close(slave)
        os.close(master)


def test_ground_truth_records_refuse_an_unknown_format():
    """The stamper looks a decoder's record end up by its format: an unknown one is refused
    where it is made, with the formats named, not later as a KeyError."""
    from bench.records import GroundTruthRecords

    with pytest.raises(ValueError, match=r"^ground-truth format must be nmea or mavlink, got 'gps'$"):
        GroundTruthRecords("gps")
