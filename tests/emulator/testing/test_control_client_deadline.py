"""The harness's ControlClient waits at most its timeout for a whole reply: a server that
trickles a reply a byte at a time cannot hold a call longer, and the client stays usable
after a timeout (its next request gets the next reply)."""

import socket
import threading
import time

import pytest

from emulator.testing import ControlClient
from emulator.testing.harness import EmulatorError

pytestmark = [pytest.mark.slow, pytest.mark.timing]  # (2.3 s: a wall-clock deadline)


def serve(listener: socket.socket, replies: list[bytes], gap_s: float) -> None:
    conn, _ = listener.accept()
    with conn:
        for reply in replies:
            conn.recv(4096)  # one request line
            for i in range(len(reply)):
                conn.sendall(reply[i : i + 1])
                time.sleep(gap_s if i < len(reply) - 1 else 0)


def test_a_trickled_reply_times_out_at_the_deadline_and_the_client_recovers():
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    slow = b'{"ok": true, "pad": "' + b"x" * 25 + b'"}\n'  # 45 bytes, one per 0.05 s: 2.2 s
    thread = threading.Thread(target=serve, args=(listener, [slow], 0.05), daemon=True)
    thread.start()
    with ControlClient(f"tcp:127.0.0.1:{port}", timeout=0.5) as client:
        t0 = time.monotonic()
        with pytest.raises(EmulatorError, match=r"^control channel tcp:127\.0\.0\.1:\d+: no reply within 0\.5 s$"):
            client.request("status")
        assert time.monotonic() - t0 < 1.5  # the deadline, not the 2.2 s of trickle
        thread.join(timeout=10)
        client.timeout = 10.0  # the rest of the trickled reply is still in the socket
        assert client.send_line(b'{"op": "status"}') == {"ok": True, "pad": "x" * 25}
    listener.close()
