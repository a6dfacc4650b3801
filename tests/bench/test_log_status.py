"""The live table of ``arva-bench log``: windowed rates and exact cells."""

from dataclasses import dataclass, field

from rich.console import Console

from bench.log_status import COLUMNS, LiveStatus, si
from bench.logger import DeviceStats


@dataclass
class Spec:
    name: str


@dataclass
class Decoder:
    errors: int = 0

    def stats(self):
        return {"errors": self.errors}


@dataclass
class FakeLogger:
    name: str
    stats: DeviceStats = field(default_factory=DeviceStats)
    decoder: Decoder = field(default_factory=Decoder)

    def __post_init__(self):
        self.spec = Spec(self.name)


def test_rates_are_over_the_window_and_a_stall_shows_zero():
    arva, gps = FakeLogger("arva"), FakeLogger("gps-rx")
    status = LiveStatus([arva, gps], window=5.0)
    status.sample(100.0)
    assert status.rates("arva") is None
    for k in range(1, 11):  # 10 s at 20 records/s and 2 kB/s; the GPS never sends
        arva.stats.records, arva.stats.bytes = 20 * k, 2000 * k
        status.sample(100.0 + k)
    assert status.rates("arva") == (20.0, 2000.0)
    assert status.rates("gps-rx") == (0.0, 0.0)
    for k in range(11, 17):  # the receiver stalls for 6 s
        status.sample(100.0 + k)
    assert status.rates("arva") == (0.0, 0.0)


def test_rows_are_exact():
    arva, gps = FakeLogger("arva"), FakeLogger("gps-rx")
    arva.stats.connected, arva.stats.last_data_mono, arva.stats.gaps = True, 109.25, 1
    arva.decoder.errors = 3
    status = LiveStatus([arva, gps])
    status.sample(100.0)
    arva.stats.records, arva.stats.bytes = 40, 123_456
    status.sample(104.0)
    assert status.rows(110.0) == [
        ("arva", "up", "10.0/s", "30.9 kB/s", "40", "3", "1", "0.8 s ago"),
        ("gps-rx", "down", "0.0/s", "0.0 B/s", "0", "0", "0", "-"),
    ]
    console = Console(width=100, record=True, color_system=None)
    console.print(status.table(12.5, 110.0))
    text = console.export_text()
    assert "arva-bench log     12.5 s" in text and all(c in text for c in COLUMNS)
    assert "30.9 kB/s" in text and "down" in text


def test_si():
    assert [si(v, "B/s") for v in (0, 5.25, 99.94, 99.96, 999.4, 999.6, 123_456, 7.5e6, 2e12)] == [
        "0.0 B/s", "5.2 B/s", "99.9 B/s", "100 B/s", "999 B/s", "1.0 kB/s", "123 kB/s", "7.5 MB/s", "2000 GB/s",
    ]
