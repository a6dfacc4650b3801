"""Reading a session full of line noise (issue 29, item 2): export, fit and replay stream
the raw logs, so their peak memory does not grow with the noise. 1 MiB of noise here; the
60 MB figures of docs/reliability.md come from tests/perf/noise_cost.py."""

from __future__ import annotations

import pytest
from noise_sessions import noise_session, peak_rss

pytestmark = [pytest.mark.slow, pytest.mark.subprocess]


READERS = {
    "export": lambda d, tmp: ["export", str(d), "--csv", str(tmp / f"{d.name}.csv")],
    "fit": lambda d, tmp: ["fit", str(d)],
    "replay": lambda d, tmp: ["replay", str(d), "--speed", "0", "--port", "pty"],
}
#: Growth of a reader's peak RSS allowed for 1 MiB of line noise (the old readers took
#: about 300 MB for it: every error record of the whole log was held at once).
NOISE_RSS_GROWTH_KB = 24_000


@pytest.fixture(scope="module")
def noisy_and_clean(tmp_path_factory):
    root = tmp_path_factory.mktemp("noise")
    noise_session(root / "noisy", 1 << 20)
    noise_session(root / "clean", 0)
    return root


@pytest.mark.parametrize("reader", sorted(READERS))
def test_a_reader_of_a_noisy_session_does_not_grow_with_the_noise(noisy_and_clean, reader):
    root = noisy_and_clean
    code, err, clean_kb, _ = peak_rss(READERS[reader](root / "clean", root))
    assert "Traceback" not in err, err
    code, err, noisy_kb, _ = peak_rss(READERS[reader](root / "noisy", root))
    assert "Traceback" not in err, err
    if reader == "export":
        assert (code, err) == (0, f"arva-bench: export: 16 rows to {root / 'noisy.csv'}; dropped: none\n")
    assert noisy_kb - clean_kb < NOISE_RSS_GROWTH_KB, (clean_kb, noisy_kb)


def test_replay_streams_a_long_noisy_log(tmp_path):
    """Replay sends bytes, it decodes nothing: what grew was the whole log held as reads
    (about 3.5 times the noise). 16 MiB of noise; the growth allowed is a quarter of it."""
    noise_session(tmp_path / "noisy", 16 << 20)
    noise_session(tmp_path / "clean", 0)
    _, err, clean_kb, _ = peak_rss(READERS["replay"](tmp_path / "clean", tmp_path))
    code, err, noisy_kb, _ = peak_rss(READERS["replay"](tmp_path / "noisy", tmp_path))
    assert code == 0 and "Traceback" not in err, err
    assert noisy_kb - clean_kb < (16 << 20) / 4 / 1024, (clean_kb, noisy_kb)
