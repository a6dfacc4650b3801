"""The example device under test against the emulator, with only the installed ``arva``
pytest plugin: the same test under the step clock and in real time.

It acquires a transmitter entering range, keeps its target when a second, closer one
appears, goes fine and located as its target comes near, and survives a 2 s unplug."""

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

DUT = Path(__file__).with_name("search_dut.py")
RATE_HZ = 10.0
SCENE = {
    "spec": 1,
    "rate_hz": RATE_HZ,
    "transmitters": [{"id": 1, "position": [120.0, 0.0, 0.0]}],  # out of range
    "receiver": {"channels": 2, "position": [0.0, 0.0, 0.0]},
}


class DeviceUnderTest:
    """search_dut.py in a subprocess; its JSON lines collected by a thread."""

    def __init__(self, port: str) -> None:
        self.proc = subprocess.Popen([sys.executable, str(DUT), port], stdout=subprocess.PIPE, text=True)
        self.epochs: dict[int, dict] = {}
        self.events: list[str] = []
        self.lock = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            msg = json.loads(line)
            with self.lock:
                if "event" in msg:
                    self.events.append(msg["event"])
                else:
                    self.epochs[msg["seq"]] = msg
                self.lock.notify_all()

    def wait_for(self, what, timeout: float = 10.0):
        """Wait until ``what(self)`` is true."""
        deadline = time.monotonic() + timeout
        with self.lock:
            while not what(self):
                left = deadline - time.monotonic()
                assert left > 0, f"timed out; epochs seen: {sorted(self.epochs)[-5:]}, events {self.events}"
                self.lock.wait(left)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=10)


class Clock:
    """Moves scene time on: steps under the step clock, waits in real time."""

    def __init__(self, emu, kind: str, dut: DeviceUnderTest) -> None:
        self.emu, self.kind, self.dut = emu, kind, dut

    def state_at(self, epoch: int) -> dict:
        """The DUT's report of epoch ``epoch`` (stepping up to it if needed)."""
        if self.kind == "step":
            while self.emu.epoch <= epoch:
                self.emu.step()
        self.dut.wait_for(lambda d: max(d.epochs, default=-1) >= epoch)
        return self.dut.epochs[epoch]

    def until(self, predicate, limit: int = 60) -> dict:
        """Move on until the DUT's latest report satisfies ``predicate`` (at most
        ``limit`` epochs). While the link is down nothing is reported: under the step
        clock each step then only waits briefly for the DUT to find its port again."""
        latest = lambda d: d.epochs[max(d.epochs)] if d.epochs else {"seq": -1}  # noqa: E731
        if self.kind == "real":
            self.dut.wait_for(lambda d: predicate(latest(d)), timeout=limit / RATE_HZ + 5)
            return latest(self.dut)
        for _ in range(limit):
            lost = bool(self.dut.events) and self.dut.events[-1] == "link_lost"
            k = self.emu.step() - 1
            if lost:  # the epoch just written may reach a port the DUT has not reopened yet
                try:
                    self.dut.wait_for(lambda d: d.events[-1] == "link_back", timeout=0.15)
                except AssertionError:
                    pass
                continue
            self.dut.wait_for(lambda d: max(d.epochs, default=-1) >= k)
            if predicate(latest(self.dut)):
                return latest(self.dut)
        raise AssertionError(f"not reached within {limit} epochs: {latest(self.dut)}")


@pytest.mark.timeout(90)
@pytest.mark.parametrize("clock", ["step", "real"])
def test_search_state_machine(arva_emulator, clock):
    emu = arva_emulator(scene=SCENE, clock=clock, speed=1.0)
    dut = DeviceUnderTest(emu.port)
    try:
        if clock == "step":
            time.sleep(0.5)  # let the DUT open its port before the first epoch
        t = Clock(emu, clock, dut)
        k = emu.epoch
        assert t.state_at(k + 2)["state"] == "no_signal"

        # Transmitter 1 enters range at 30 m on the dipole axis: acquired, coarse.
        k = emu.set_transmitter(1, position=[30.0, 0.0, 0.0])
        assert t.state_at(k) == {"seq": k, "state": "coarse", "target": 1, "d": 2751}

        # A second transmitter appears, much closer: the target stays transmitter 1.
        k = emu.set_transmitter(2, position=[0.0, 5.0, 0.0])
        assert t.state_at(k + 1) == {"seq": k + 1, "state": "coarse", "target": 1, "d": 2751}

        # Transmitter 1 comes near: fine at 8 m (d = 734 cm), located at 2 m (183 cm).
        k = emu.set_transmitter(1, position=[8.0, 0.0, 0.0])
        assert t.state_at(k + 1)["state"] == "fine"
        k = emu.set_transmitter(1, position=[2.0, 0.0, 0.0])
        assert t.state_at(k + 1) == {"seq": k + 1, "state": "located", "target": 1, "d": 183}

        # Pull the cable for 2 s of scene time: the DUT notices, reopens, keeps its target.
        k = emu.fault("disconnect", seconds=2.0)
        dut.wait_for(lambda d: "link_lost" in d.events)  # the port vanished at once
        after = t.until(lambda m: m["seq"] >= k + 2 * RATE_HZ)
        assert after["state"] == "located" and after["target"] == 1
        assert dut.events[:2] == ["link_lost", "link_back"]
        missing = [s for s in range(k, int(k + 2 * RATE_HZ)) if s in dut.epochs]
        assert missing == []  # nothing arrived during the outage
    finally:
        dut.stop()
