"""Loopback UDP traffic, as other tests and servers on a busy machine make.

Run as ``python -m tests.harness.loopback_noise SECONDS``: random 64-byte datagrams to a socket
of its own on 127.0.0.1 (20 every ~2 ms), read back so nothing queues. Nothing leaves loopback.
"""

from __future__ import annotations

import os
import socket
import sys
import time


def send_noise(seconds: float) -> None:
    """Send and drain datagrams on 127.0.0.1 for ``seconds``."""
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out,
    ):
        sink.bind(("127.0.0.1", 0))
        sink.setblocking(False)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for _ in range(20):
                out.sendto(os.urandom(64), sink.getsockname())
            try:
                while True:
                    sink.recv(2048)
            except BlockingIOError:
                pass
            time.sleep(0.002)


if __name__ == "__main__":
    send_noise(float(sys.argv[1]))
