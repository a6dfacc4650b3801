"""The ground-truth readers against real receivers: gpsd's regression captures.

For every ``X.log`` in the gpsd corpus (``../shared/corpus/gpsd-nmea`` beside the repo; we
only read it, never copy it), the whole log is fed to :class:`GroundTruthReader` in
random-sized chunks. It must not raise, must finish, must hold back at most one line,
must give the same records as one big chunk, and every fix gpsd decoded -- each ``TPV``
in ``X.log.chk`` with mode >= 2, lat, lon and time -- must come out of our reader as a
GGA/RMC/GLL record with the same time (to the millisecond gpsd prints) and lat/lon within
1e-6 deg. Where gpsd's TPV carries ``altHAE`` and our GGA record of that epoch has one
(the receiver sent the geoid separation), they must agree to 1 mm.

Two kinds of documented difference, each as narrow as we could make it:

* ``WEEK_ROLLOVER``: gpsd moves dates that look older than its build by 1024 GPS weeks
  (a receiver week-rollover heuristic); our reader reports the date the receiver sent.
  For these logs the expected time is gpsd's minus exactly 1024 weeks.
* ``EXCLUDED``: TPVs we could not match, per log, by exact timestamp, with the reason;
  empty now. It held 18 fixes gpsd built from ``$GPGLL`` (a Garmin's extra GLL fix on odd
  seconds, an eXplorist's GLL with odd milliseconds, a Triton epoch whose GGA the capture
  cut off) until the reader learnt GLL. The test fails if an excluded fix starts matching
  (stale entry) or if any other fix does not.
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from functools import cache

import pytest
import repo_paths

from bench.ground_truth import Attitude, GpsFix, GroundTruthReader
from emulator.frames.attitude import hpr_to_quaternion

CORPUS = repo_paths.ROOT.parent / "shared" / "corpus" / "gpsd-nmea"
LOGS = sorted(p.name for p in CORPUS.glob("*.log")) if CORPUS.is_dir() else []
MISSING = f"gpsd corpus not found at {CORPUS} (expected ../shared/corpus/gpsd-nmea beside the repo)"

GPS_WEEKS_1024 = timedelta(weeks=1024)

#: log -> why gpsd's dates are 1024 weeks later than the receiver's.
WEEK_ROLLOVER = {
    "rst39.log": "RMC/ZDA date 2014-02-19; gpsd reports 2033-10-05",
    "neo-m8n.log": "RMC date 2015-03-18; gpsd reports 2034-11-01",
}

#: log -> (reason, exact TPV times, as gpsd prints them, that we cannot match). Empty
#: since the reader takes GLL too: every fix gpsd decoded from this corpus is ours.
EXCLUDED: dict[str, tuple[str, frozenset[str]]] = {}

#: log -> why gpsd's altHAE is not the GGA's MSL + separation.
ALT_EXCLUDED = {
    "ac12_binary.log": "gpsd takes the altitude from $PASHR,POS (058.48 m HAE), not from the "
    "GGA's 072.35 m MSL + -13.9 m separation",
}

#: The corpus as shipped: logs with at least one TPV to match, and the totals.
EXPECTED_TOTALS = {"tpv": 2827, "matched": 2827, "excluded": 0, "altitudes": 2119}


@dataclass
class LogResult:
    records: list[GpsFix | Attitude]
    stats: dict[str, int]
    max_pending: int
    tpv: int = 0
    matched: int = 0
    unmatched: set[str] = field(default_factory=set)  # TPV times
    unmatched_tpvs: int = 0
    altitudes: int = 0
    altitude_mismatches: list[str] = field(default_factory=list)


def _tpvs(name: str) -> list[dict]:
    out = []
    for line in (CORPUS / (name + ".chk")).read_text(encoding="utf-8", errors="replace").splitlines():
        if not line.startswith("{"):
            continue  # gpsd's .chk also echoes the input sentences
        obj = json.loads(line)
        if obj.get("class") == "TPV" and obj.get("mode", 0) >= 2 and all(k in obj for k in ("lat", "lon", "time")):
            out.append(obj)
    return out


def _ms(t: datetime) -> str:
    return t.isoformat(timespec="milliseconds").replace("+00:00", "Z")


@cache
def run_log(name: str) -> LogResult:
    data = (CORPUS / name).read_bytes()
    reader = GroundTruthReader()
    rng = random.Random(name)  # reproducible chunking per log
    records: list[GpsFix | Attitude] = []
    max_pending = 0
    i = 0
    while i < len(data):
        n = rng.choice((1, 2, 7, rng.randint(1, 64), rng.randint(1, 4096)))
        records += reader.feed(data[i : i + n])
        max_pending = max(max_pending, reader.pending)
        i += n
    records += reader.flush()
    result = LogResult(records, dict(reader.stats), max_pending)

    by_time: dict[str, list[GpsFix]] = {}
    for rec in records:
        if isinstance(rec, GpsFix) and rec.lat is not None and rec.utc is not None:
            by_time.setdefault(_ms(rec.utc), []).append(rec)
    shift = GPS_WEEKS_1024 if name in WEEK_ROLLOVER else timedelta(0)
    for tpv in _tpvs(name):
        result.tpv += 1
        t = datetime.fromisoformat(tpv["time"].replace("Z", "+00:00")) - shift
        same = [
            f
            for f in by_time.get(_ms(t), [])
            if abs(f.lat - tpv["lat"]) <= 1e-6 and abs(f.lon - tpv["lon"]) <= 1e-6  # type: ignore[operator]
        ]
        if not same:
            result.unmatched.add(tpv["time"])
            result.unmatched_tpvs += 1
            continue
        result.matched += 1
        hae = [f.alt_hae for f in same if f.sentence == "GGA" and f.alt_hae is not None]
        if "altHAE" in tpv and hae:
            if not any(abs(h - tpv["altHAE"]) <= 1e-3 for h in hae):
                result.altitude_mismatches.append(f"{tpv['time']}: gpsd {tpv['altHAE']}, ours {hae}")
            elif name not in ALT_EXCLUDED:
                result.altitudes += 1
    return result


@pytest.mark.skipif(not LOGS, reason=MISSING)
@pytest.mark.timeout(30)
@pytest.mark.parametrize("name", LOGS or ["-"])
def test_log_matches_gpsd(name):
    res = run_log(name)
    assert res.stats["bytes"] == (CORPUS / name).stat().st_size
    assert res.max_pending <= 256
    assert res.stats["fixes"] == sum(isinstance(r, GpsFix) for r in res.records)
    assert res.stats.get("attitudes", 0) == sum(isinstance(r, Attitude) for r in res.records)
    reason, excluded = EXCLUDED.get(name, ("", frozenset()))
    assert res.unmatched == excluded, f"unmatched gpsd fixes (exclusion: {reason or 'none'})"
    assert res.matched == res.tpv - res.unmatched_tpvs
    if name in ALT_EXCLUDED:
        assert res.altitude_mismatches, f"stale ALT_EXCLUDED entry: {ALT_EXCLUDED[name]}"
    else:
        assert res.altitude_mismatches == []


@pytest.mark.skipif(not LOGS, reason=MISSING)
@pytest.mark.parametrize("name", ["ublox-8.log", "rst39.log", "gp-320fw-2019-04-07-coldboot.log", "ac12_binary.log"])
def test_chunking_does_not_change_records(name):
    data = (CORPUS / name).read_bytes()
    whole = GroundTruthReader()
    expected = whole.feed(data) + whole.flush()
    bytewise = GroundTruthReader()
    got = [rec for i in range(len(data)) for rec in bytewise.feed(data[i : i + 1])] + bytewise.flush()
    assert got == expected == run_log(name).records
    assert dict(bytewise.stats) == dict(whole.stats)


@pytest.mark.skipif(not LOGS, reason=MISSING)
def test_corpus_totals(capsys):
    results = {name: run_log(name) for name in LOGS}
    totals = {
        "tpv": sum(r.tpv for r in results.values()),
        "matched": sum(r.matched for r in results.values()),
        "excluded": sum(r.unmatched_tpvs for r in results.values()),
        "altitudes": sum(r.altitudes for r in results.values()),
    }
    with_fixes = sum(1 for r in results.values() if r.tpv)
    with capsys.disabled():
        print(
            f"\ngpsd corpus: {len(results)} logs, {with_fixes} with gpsd fixes; "
            f"{totals['matched']}/{totals['tpv']} fixes matched, {totals['excluded']} excluded "
            f"({', '.join(EXCLUDED)}), {totals['altitudes']} HAE altitudes checked"
        )
    assert set(EXCLUDED) | set(WEEK_ROLLOVER) | set(ALT_EXCLUDED) <= set(results)
    assert totals == EXPECTED_TOTALS


@pytest.mark.skipif(not LOGS, reason=MISSING)
def test_rst39_attitudes():
    """The OxTS INS: 100 $PASHR, dated by the RMC that follows the first of them."""
    atts = [r for r in run_log("rst39.log").records if isinstance(r, Attitude)]
    assert len(atts) == 100
    first, second, last = atts[0], atts[1], atts[-1]
    # $PASHR,204132.000,010.51,T,+00.39,-00.79,-00.84,0.151,0.075,0.555,1,0*03
    assert (first.time_of_day.isoformat(), first.utc) == ("20:41:32", None)  # before any date
    assert (first.heading, first.roll, first.pitch, first.heave) == (10.51, 0.39, -0.79, -0.84)
    assert (first.roll_accuracy, first.pitch_accuracy, first.heading_accuracy) == (0.151, 0.075, 0.555)
    assert (first.gps_quality, first.ins_status) == (1, 0)
    assert first.quaternion == tuple(hpr_to_quaternion(10.51, 0.39, -0.79).tolist())
    # $PASHR,204132.040,010.99,T,+00.41,-00.75,-00.84,0.151,0.088,0.569,1,0*0D, after the RMC of 190214
    assert _ms(second.utc) == "2014-02-19T20:41:32.040Z"
    assert (second.heading, second.roll, second.pitch) == (10.99, 0.41, -0.75)
    assert all(a.utc is not None for a in atts[1:])
    times = [a.utc for a in atts[1:]]
    assert times == sorted(times)
    lines = [ln for ln in (CORPUS / "rst39.log").read_text().splitlines() if ln.startswith("$PASHR")]
    fields = lines[-1].split("*")[0].split(",")
    assert (last.heading, last.roll, last.pitch) == (float(fields[2]), float(fields[4]), float(fields[5]))


@pytest.mark.skipif(not LOGS, reason=MISSING)
def test_fuzzy_cases_exact_times():
    """gpsd's 'fuzzy arithmetic' sentences: times such as 132820.70 must be exact."""
    res = run_log("nmea-fuzzy-cases.log")
    fixes = [r for r in res.records if isinstance(r, GpsFix)]
    assert len(fixes) == 28
    assert {k: res.stats.get(k, 0) for k in ("bad_checksum", "malformed", "no_checksum")} == {
        "bad_checksum": 0,
        "malformed": 0,
        "no_checksum": 0,
    }
    lines = [ln for ln in (CORPUS / "nmea-fuzzy-cases.log").read_text().splitlines() if ln.startswith("$")]
    for fix, line in zip(fixes, lines, strict=True):
        hhmmss = line.split(",")[1]
        assert fix.time_of_day.strftime("%H%M%S.%f")[:9] == hhmmss
    assert fixes[0].lat == pytest.approx(41 + 34.49821229 / 60, abs=1e-10)
    assert fixes[0].alt_hae == pytest.approx(278.020 - 31.442, abs=1e-9)
