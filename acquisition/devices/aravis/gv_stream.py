"""How msflash opens a GigE Vision stream: the socket Aravis reads packets from, and its size.

Two of Aravis 0.8's stream defaults lose frames on a loaded host, for the GigE Vision fake on
127.0.0.1 and for a camera on a real network alike:

**The packet socket.** A process allowed raw sockets gets Aravis's ``AF_PACKET`` ring, bound to the
interface before its packet filter is attached: any datagram in that window can come out as a ``cleared``
"frame" that never was (docs/steady-tests.md). The ordinary UDP socket bound to the stream port receives
only datagrams sent to that port, so msflash always asks for it (``ARV_GV_STREAM_OPTION_PACKET_SOCKET_DISABLED``).

**The socket buffer.** Aravis's ``auto`` mode sets the receive buffer to one payload, less than the kernel
charges for a frame's datagrams, so a descheduled stream thread drops packets. msflash fixes it at
:func:`socket_buffer_bytes`: room for about two whole frames, never below 1 MiB (capped at ``net.core.rmem_max``).

An incomplete frame is still possible (a real link drops packets; the fake never resends): the
camera reports it as such and never delivers it (:meth:`AravisCamera.next_frame`).
"""

from __future__ import annotations

from typing import Any

import gi

gi.require_version("Aravis", "0.8")
from gi.repository import Aravis  # noqa: E402

SOCKET_BUFFER_FLOOR_BYTES = 1 << 20
"""Smallest receive buffer msflash asks for (the system default is about 208 KiB)."""
SOCKET_BUFFER_CEILING_BYTES = 64 << 20
"""Largest receive buffer msflash asks for (beyond, frames are better served by more buffers)."""
FRAMES_IN_SOCKET = 4
"""Payloads' worth of receive buffer: about two frames, at the kernel's two-to-one charge per datagram."""


def socket_buffer_bytes(payload: int) -> int:
    """The receive buffer for a stream of ``payload``-byte frames: ``FRAMES_IN_SOCKET × payload`` clipped to
    [1 MiB, 64 MiB].

    Examples
    --------
    >>> socket_buffer_bytes(6144)
    1048576
    >>> socket_buffer_bytes(1280 * 1024 * 2)
    10485760
    """
    return int(min(SOCKET_BUFFER_CEILING_BYTES, max(SOCKET_BUFFER_FLOOR_BYTES, FRAMES_IN_SOCKET * int(payload))))


def create_gv_stream(camera: Any, payload: int) -> Any:
    """Create the stream of the GigE Vision ``camera`` on a UDP socket sized for ``payload`` (as
    ``Aravis.Camera.create_stream`` returns it: None possible).

    Raises
    ------
    GLib.Error
        Aravis could not create the stream (the caller names the step).
    """
    device = camera.get_device()
    device.set_stream_options(Aravis.GvStreamOption.PACKET_SOCKET_DISABLED)
    stream = camera.create_stream(None, None)
    if stream is not None:
        stream.set_property("socket-buffer", Aravis.GvStreamSocketBuffer.FIXED)
        stream.set_property("socket-buffer-size", socket_buffer_bytes(payload))
    return stream
