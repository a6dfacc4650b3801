"""Build the C codec with the system compiler and drive it from Python (ctypes).

Used by tests/firmware_proto/test_vectors.py, tests/firmware_proto/test_c_codec.py and tests/perf/bench_decoder.py.
Builds go to a fresh temporary directory once per process.
"""

from __future__ import annotations

import atexit
import ctypes
import functools
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
C_DIR = ROOT / "firmware_proto" / "c"
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
SANITIZE = ["-fsanitize=address,undefined"]


def find_cc() -> str | None:
    return shutil.which(os.environ.get("CC", "cc"))


@functools.cache
def build_dir() -> Path:
    path = Path(tempfile.mkdtemp(prefix="arva-c-"))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


def compile_c(args: list[str]) -> None:
    cc = find_cc()
    if cc is None:
        raise RuntimeError("no C compiler")
    proc = subprocess.run([cc, *args], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0:
        raise RuntimeError(f"{cc} {' '.join(args)} failed:\n{proc.stderr}")


@functools.cache
def sanitizers_work() -> bool:
    """True when -fsanitize=address,undefined compiles *and* runs here."""
    src = build_dir() / "san.c"
    exe = build_dir() / "san"
    src.write_text("int main(void) { return 0; }\n")
    try:
        compile_c([*SANITIZE, str(src), "-o", str(exe)])
        return subprocess.run([str(exe)], timeout=30).returncode == 0
    except (RuntimeError, OSError, subprocess.TimeoutExpired):
        return False


@functools.cache
def build_runner() -> Path:
    """The golden-vector runner, strict warnings, sanitizers when available."""
    exe = build_dir() / "test_vectors"
    flags = STRICT + ["-O1", "-g"] + (SANITIZE if sanitizers_work() else [])
    sources = [str(C_DIR / f) for f in ("arva_codec.c", "test_support.c", "test_vectors.c")]
    compile_c([*flags, *sources, "-lm", "-o", str(exe)])
    return exe


@functools.cache
def build_library() -> ctypes.CDLL:
    """Codec + test support as a shared library for ctypes (no sanitizers: they cannot
    be loaded into an uninstrumented Python)."""
    so = build_dir() / "libarva.so"
    sources = [str(C_DIR / f) for f in ("arva_codec.c", "test_support.c")]
    compile_c([*STRICT, "-O2", "-fPIC", "-shared", *sources, "-o", str(so)])
    lib = ctypes.CDLL(str(so))
    size_t, p = ctypes.c_size_t, ctypes.c_void_p
    lib.arva_test_decoder_size.restype = size_t
    lib.arva_decoder_init.argtypes = [p, ctypes.c_int]
    lib.arva_decoder_set_max_range.argtypes = [p, ctypes.c_long]
    lib.arva_decoder_set_max_range.restype = ctypes.c_int
    lib.arva_test_feed.argtypes = [p, ctypes.c_char_p, size_t, p, size_t]
    lib.arva_test_feed.restype = size_t
    lib.arva_test_flush.argtypes = [p, p, size_t]
    lib.arva_test_flush.restype = size_t
    lib.arva_test_idle.argtypes = [p, p, size_t]
    lib.arva_test_idle.restype = size_t
    lib.arva_test_stats.argtypes = [p, p, size_t]
    lib.arva_test_stats.restype = size_t
    lib.arva_test_count.argtypes = [p, ctypes.c_char_p, size_t]
    lib.arva_test_count.restype = ctypes.c_ulong
    lib.arva_encode_epoch.argtypes = [p, size_t, ctypes.c_uint32, p, ctypes.c_uint]
    lib.arva_encode_epoch.restype = size_t
    lib.arva_encode_parvh.argtypes = [p, size_t, ctypes.c_uint32, ctypes.c_uint, ctypes.c_int32,
                                      ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p]  # fmt: skip
    lib.arva_encode_parvh.restype = size_t
    return lib


_FAIL = ctypes.c_size_t(-1).value


class CDecoder:
    """The C decoder behind the same calls as the Python one; events come back as the
    canonical text lines of :func:`firmware_proto.golden.event_text`."""

    def __init__(self, expect_fields: bool = False, max_d_cm: int | None = None) -> None:
        self.lib = build_library()
        self._state = ctypes.create_string_buffer(self.lib.arva_test_decoder_size())
        self.lib.arva_decoder_init(self._state, int(expect_fields))
        if max_d_cm is not None and self.lib.arva_decoder_set_max_range(self._state, max_d_cm) != 0:
            raise ValueError(f"max_d_cm {max_d_cm} refused")

    def _call(self, fn, *args, cap: int) -> list[str]:  # type: ignore[no-untyped-def]
        out = ctypes.create_string_buffer(cap)
        n = fn(self._state, *args, out, cap)
        if n == _FAIL:
            raise RuntimeError("C event text buffer too small")
        return out.raw[:n].decode().splitlines()

    def feed(self, data: bytes) -> list[str]:
        return self._call(self.lib.arva_test_feed, bytes(data), len(data), cap=65536 + 64 * len(data))

    def flush(self) -> list[str]:
        return self._call(self.lib.arva_test_flush, cap=65536)

    def idle(self) -> list[str]:
        return self._call(self.lib.arva_test_idle, cap=65536)

    def stats(self) -> str:
        out = ctypes.create_string_buffer(2048)
        n = self.lib.arva_test_stats(self._state, out, 2048)
        return out.raw[:n].decode()

    def count(self, data: bytes) -> int:
        """Decode without describing anything; returns the number of valid sentences."""
        return self.lib.arva_test_count(self._state, data, len(data))


def c_encode_epoch(seq: int, slots: list[tuple[int, int, int]]) -> bytes | None:
    lib = build_library()
    arr = (ctypes.c_int32 * (3 * max(1, len(slots))))(*[v for s in slots for v in s])
    out = ctypes.create_string_buffer(82 * 99)
    n = lib.arva_encode_epoch(out, len(out), seq, arr, len(slots))
    return out.raw[:n] if n else None


def c_encode_parvh(seq: int, k: int, tx_id: int, h: tuple[bytes, bytes, bytes]) -> bytes | None:
    lib = build_library()
    out = ctypes.create_string_buffer(128)
    n = lib.arva_encode_parvh(out, len(out), seq, k, tx_id, *h)
    return out.raw[:n] if n else None
