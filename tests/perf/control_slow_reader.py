"""What a control request costs while another client's ``step`` writes to a slow pty
reader (emulator/control/server.py: a slice may wait in a port write, up to the step
clock's drain wait, emulator.output.scheduler.STEP_DRAIN_WAIT, without progress).

An ``arva-emulate`` on the embedded default scene (100 bytes an epoch) under the step
clock, one pty, control on a unix socket. Client A asks for a step of 100,000 epochs;
a reader reads the pty ``--chunk`` bytes every ``--every`` s (a reader that keeps
reading, slowly: it is given as long as it makes progress); client B sends ``status``
every 0.2 s (and once a malformed line, which needs no emulator), and the script prints
how long each reply took. Then the reader stops reading altogether (seen, then idle: a
write waits up to the drain wait without progress, then the port drops until it reads
again) and B's status is timed again.
Prints the figures and the load average; writes nothing. Run it on two trees to compare
(PYTHONPATH=OTHER_TREE python OTHER_TREE/tests/perf/control_slow_reader.py).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import threading
import time

from emulator.testing import EmulatorProcess


def timed(sock: socket.socket, line: bytes) -> tuple[float, dict]:
    t0 = time.monotonic()
    sock.sendall(line)
    data = b""
    while not data.endswith(b"\n"):
        chunk = sock.recv(65536)
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return time.monotonic() - t0, json.loads(data)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--chunk", type=int, default=1000)
    ap.add_argument("--every", type=float, default=0.1)
    ap.add_argument("--requests", type=int, default=20)
    args = ap.parse_args()
    path = f"/tmp/arva-slow-{os.getpid()}.sock"
    emu = EmulatorProcess("--port", "pty", "--clock", "step", "--control", f"unix:{path}")
    try:
        fd = os.open(emu.ports["arva"], os.O_RDONLY | os.O_NOCTTY)
        reading = threading.Event()
        reading.set()
        done = threading.Event()

        def reader() -> None:
            while not done.is_set():
                if reading.is_set():
                    os.read(fd, args.chunk)
                time.sleep(args.every)

        threading.Thread(target=reader, daemon=True).start()
        a = socket.socket(socket.AF_UNIX)
        a.connect(path)
        b = socket.socket(socket.AF_UNIX)
        b.connect(path)
        b.settimeout(30)
        a.sendall(b'{"op": "step", "n": 100000}\n')
        time.sleep(3)  # the pty buffer fills; from now on every slice waits for the reader
        slow = []
        for i in range(args.requests):
            if i == args.requests // 2:
                time.sleep(0.2)
                bad, _ = timed(b, b"nonsense\n")  # needs no emulator
            dt, reply = timed(b, b'{"op": "status"}\n')
            slow.append(dt)
            time.sleep(0.2)
        epoch = reply["epoch"]
        reading.clear()  # seen, now idle
        time.sleep(0.5)
        idle = []
        for _ in range(5):
            dt, reply = timed(b, b'{"op": "status"}\n')
            idle.append(dt)
            time.sleep(0.2)
        load = os.getloadavg()[0]
        ms = lambda xs: f"median {statistics.median(xs) * 1e3:.0f} ms, max {max(xs) * 1e3:.0f} ms"  # noqa: E731
        print(f"reader {args.chunk} B every {args.every} s: status {ms(slow)} over {len(slow)}; "
              f"epoch {epoch} after them")
        print(f"reader idle: status {ms(idle)} over {len(idle)} ({', '.join(f'{x * 1e3:.0f}' for x in idle)} ms), epoch {reply['epoch']}")
        print(f"malformed line during the slow step: answered in {bad * 1e3:.0f} ms")
        print(f"load average (1 min): {load:.1f}")
        done.set()
        timed(b, b'{"op": "quit"}\n')
        emu.wait(timeout=20)
    finally:
        emu.kill()


if __name__ == "__main__":
    main()
