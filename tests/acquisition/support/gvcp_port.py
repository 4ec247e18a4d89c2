"""Whether something listens on the GigE Vision control port (a fake camera) on loopback."""

from __future__ import annotations

import socket

GVCP_PORT = 3956
"""The GigE Vision control port (UDP)."""


def gvcp_port_in_use(address: str = "127.0.0.1", port: int = GVCP_PORT) -> bool:
    """True when ``address:port`` cannot be bound: a fake camera (or another program) holds it."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((address, port))
        except OSError:
            return True
    return False
