"""Line noise is counted, not multiplied (issue 29, item 1): a noisy line gives a session
whose size stays within twice the bytes received, the raw bytes exact, every error
counted once (error records sampled, the rest summed), also in the dashboard's counters.
Small inputs (a few hundred kB); the 60 MB figures are measured by tests/perf/noise_cost.py."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from hostile_streams import chunkings, hostile_streams, split
from hypothesis import given, settings
from hypothesis import strategies as st
import pytest

from bench.dash.messages import LinkStatus
from bench.dash.sources import DeviceFeed
from bench.ingest.reader import Device, DeviceSpec
from bench.ingest.stamp import ERROR_RECORDS_PER_SECOND, FEED_SLICE
from bench.logger import SessionListener
from bench.session import SessionWriter, read_jsonl, read_raw

FAST = 12_000_000  # bit/s: a 64 KiB read spans 55 ms of line time, so reads keep their own second
CHUNK = 65536


def log_noise(directory, reads: list[tuple[float, bytes]], baudrate: int = FAST, kind: str = "arva", name: str = "arva"):
    """Log ``reads`` (mono, bytes) of one device as ``arva-bench log`` does; its summary."""
    spec = DeviceSpec(name, kind, "x", baudrate=baudrate)
    writer = SessionWriter(directory, {"devices": {name: spec.manifest()}})
    device = Device(spec)
    listener = SessionListener(writer)
    for mono, data in reads:
        listener.on_read(device, device.ingest(data, mono, 1.8e9 + mono))
    end = reads[-1][0] + 0.5
    listener.on_read(device, device.stop(end, 1.8e9 + end))
    summary = listener.summary([device])
    writer.close(devices=summary)
    return summary[name]


def session_bytes(directory) -> int:
    return sum(p.stat().st_size for p in directory.iterdir())


@pytest.mark.slow
def test_four_reads_of_dollars_in_one_second_are_ten_records_and_one_sum(tmp_path):
    noise = b"$" * CHUNK
    summary = log_noise(tmp_path / "s", [(100.0 + 0.25 * k, noise) for k in range(4)])
    received = 4 * CHUNK
    errors = received - 1  # every '$' truncates the one before; the last is cut by the stop, no error
    assert summary["decoder"]["errors"] == errors
    assert summary["decoder"]["error_records_suppressed"] == errors - ERROR_RECORDS_PER_SECOND
    records = [{k: v for k, v in r.items() if k not in ("mono", "utc")} for r in read_jsonl(tmp_path / "s" / "arva.jsonl")]
    suppressed = errors - ERROR_RECORDS_PER_SECOND
    assert records == [{"error": "TRUNCATED", "offset": i, "length": 1} for i in range(ERROR_RECORDS_PER_SECOND)] + [
        {"suppressed": suppressed, "kinds": {"TRUNCATED": suppressed}, "length": suppressed}
    ]
    assert b"".join(r.data for r in read_raw(tmp_path / "s" / "arva.raw").reads) == noise * 4
    assert session_bytes(tmp_path / "s") <= 2 * received


def test_each_second_of_noise_gets_its_sample_and_its_sum(tmp_path):
    noise = b"$" * CHUNK
    log_noise(tmp_path / "s", [(100.0, noise), (101.5, noise), (103.0, noise)])
    records = list(read_jsonl(tmp_path / "s" / "arva.jsonl"))
    errors = [r for r in records if "error" in r]
    sums = [r["suppressed"] for r in records if "suppressed" in r]
    per_read = CHUNK - ERROR_RECORDS_PER_SECOND  # a read's first '$' ends the error of the read before
    assert (len(errors), sums) == (3 * ERROR_RECORDS_PER_SECOND, [per_read - 1, per_read, per_read])
    # The sums come in order: each before the first record of a later second, the last at the stop.
    kinds = ["error" if "error" in r else "sum" for r in records]
    assert kinds == (["error"] * ERROR_RECORDS_PER_SECOND + ["sum"]) * 3
    assert [r["mono"] for r in records] == sorted(r["mono"] for r in records)


def test_noise_between_epochs_does_not_cost_them(tmp_path):
    from firmware_proto.sentences import encode_parva

    reads = []
    for k in range(20):
        reads.append((100.0 + 0.1 * k, b"$" * 3000 + encode_parva(k, 1, 1, 1, 1905, 21)))
    summary = log_noise(tmp_path / "s", reads)
    records = list(read_jsonl(tmp_path / "s" / "arva.jsonl"))
    assert [r["seq"] for r in records if "seq" in r] == list(range(20))
    written = sum(1 for r in records if "error" in r) + sum(r["suppressed"] for r in records if "suppressed" in r)
    assert written == summary["decoder"]["errors"] == 20 * 3000


def test_ground_truth_noise_is_sampled_too(tmp_path):
    # A GPS line of '$$' lines: one error record per line without sampling.
    noise = b"$$\r\n" * 20000
    summary = log_noise(tmp_path / "s", [(100.0, noise)], baudrate=FAST, kind="gps", name="gps-rx")
    records = list(read_jsonl(tmp_path / "s" / "gps-rx.jsonl"))
    flagged = [r for r in records if "error" in r]
    assert len(flagged) == ERROR_RECORDS_PER_SECOND
    assert summary["decoder"]["error_records_suppressed"] == sum(r["suppressed"] for r in records if "suppressed" in r) > 0
    assert session_bytes(tmp_path / "s") <= 2 * len(noise)


def test_a_read_is_fed_in_bounded_slices():
    """However long a read, the decoder is never handed more than FEED_SLICE bytes at once
    (the events of one slice are all the noise ever held in memory)."""
    spec = DeviceSpec("arva", "arva", "x", baudrate=FAST)
    device = Device(spec)
    sizes = []
    feed = device.decoder.feed
    device.decoder.feed = lambda data: (sizes.append(len(data)), feed(data))[1]
    device.ingest(b"$" * (10 * FEED_SLICE + 7), 1.0, 2.0)
    assert max(sizes) == FEED_SLICE and sum(sizes) == 10 * FEED_SLICE + 7


@pytest.mark.slow
def test_the_dashboard_counts_every_error_of_a_sampled_stream():
    posted = []
    feed = DeviceFeed(DeviceSpec("arva", "arva", "x", "rx", baudrate=FAST), posted.append)
    for k in range(3):
        feed.on_read(feed.device, feed.device.ingest(b"$" * CHUNK, 10.0 + k, 0.0))
    feed.on_read(feed.device, feed.device.stop(14.0, 0.0))
    feed.status(force=True)
    c = [m for m in posted if isinstance(m, LinkStatus)][-1].counters
    assert (c.errors, c.dropped_bytes) == (3 * CHUNK - 1, 3 * CHUNK - 1)


def test_the_stop_event_reports_the_sum(tmp_path):
    log_noise(tmp_path / "s", [(100.0, b"$" * CHUNK)])
    stop = [e for e in read_jsonl(tmp_path / "s" / "events.jsonl") if e["event"] == "stop"][0]
    assert stop["devices"]["arva"]["decoder"]["error_records_suppressed"] == CHUNK - 1 - ERROR_RECORDS_PER_SECOND
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert manifest["summary"]["devices"]["arva"]["decoder"]["errors"] == CHUNK - 1



@pytest.mark.slow
@settings(max_examples=30, deadline=None)
@given(hostile_streams(max_epochs=6), st.integers(0, 20000), st.booleans(), st.data())
def test_any_hostile_stream_with_a_flood_logs_every_intact_epoch_and_counts_every_error(stream, flood, first, data):
    """A hostile stream (tests/hostile_streams.py) with a flood of '$' before or after it,
    cut into reads anyhow, logged within one second: every intact epoch is in the session,
    at most 10 error records are written, and written plus summed errors are the decoder's."""
    wire = b"$" * flood + stream.data if first else stream.data + b"$" * flood
    cuts = data.draw(chunkings(wire))
    reads = [(100.0 + 0.01 * i, chunk) for i, chunk in enumerate(split(wire, cuts)) if chunk] or [(100.0, b"")]
    with tempfile.TemporaryDirectory() as tmp:
        summary = log_noise(Path(tmp) / "s", reads)
        records = list(read_jsonl(Path(tmp) / "s" / "arva.jsonl")) if (Path(tmp) / "s" / "arva.jsonl").exists() else []
        raw = Path(tmp) / "s" / "arva.raw"
        assert b"".join(r.data for r in read_raw(raw).reads) == wire if raw.exists() else wire == b""
    logged = {r["seq"] for r in records if "seq" in r and r["complete"]}
    intact = {e.seq for e, ok in zip(stream.epochs, stream.intact) if ok}
    assert intact <= logged
    errors = [r for r in records if "error" in r]
    assert len(errors) <= ERROR_RECORDS_PER_SECOND
    assert len(errors) + sum(r["suppressed"] for r in records if "suppressed" in r) == summary["decoder"]["errors"]
