"""The GigE Vision stream msflash opens (devices/aravis/gv_stream.py) and the buffers it never fills.

A stray datagram reaching the stream socket makes Aravis hand back a buffer untouched (status
``cleared``); the camera must skip it, count it, and deliver the real frames after it.
"""

from __future__ import annotations

import socket
import struct
import time
from types import ModuleType
from typing import Any

import pytest

from msflash.acquisition.devices.aravis.gv_stream import socket_buffer_bytes
from msflash.acquisition.plan import CapturePlan, CaptureStep

pytestmark = pytest.mark.aravis


def _plan(n: int) -> CapturePlan:
    return CapturePlan(
        tuple(CaptureStep(i, "ambient" if i == 0 else "led", (0.0,), 2_000.0) for i in range(n)), trigger="software"
    )


def test_socket_buffer_holds_frames_within_bounds() -> None:
    assert socket_buffer_bytes(1) == 1 << 20
    assert socket_buffer_bytes(3 << 20) == 12 << 20
    assert socket_buffer_bytes(1 << 30) == 64 << 20


def test_the_stream_uses_the_udp_socket_with_a_fixed_buffer(aravis: ModuleType, gv_camera: Any) -> None:
    from gi.repository import Aravis

    gv_camera.prepare(_plan(2))
    stream = gv_camera._pool.stream
    assert gv_camera._device.get_stream_options() == Aravis.GvStreamOption.PACKET_SOCKET_DISABLED
    assert stream.get_property("socket-buffer") == Aravis.GvStreamSocketBuffer.FIXED
    assert stream.get_property("socket-buffer-size") == socket_buffer_bytes(gv_camera._pool.payload)


def test_a_stray_datagram_is_skipped_and_the_frames_after_it_delivered(aravis: ModuleType, gv_camera: Any) -> None:
    plan = _plan(3)
    gv_camera.prepare(plan)
    port = gv_camera._pool.stream.get_port()
    gv_camera.start()
    # A GVSP-sized header of no content type Aravis knows (0x7f); its block id 0x8000 is far from
    # the fake's first ids, so Aravis does not take the real frames for late ones afterwards.
    stray = struct.pack(">HHI", 0, 0x8000, 0x7F000001) + bytes(32)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        sender.sendto(stray, ("127.0.0.1", port))
    deadline = time.monotonic() + 60.0  # only a failure waits this long
    while gv_camera.stats.buffers_unfilled == 0:  # the pump counts it before any frame is triggered
        assert time.monotonic() < deadline, "the stray datagram's buffer never came back"
        time.sleep(0.001)
    ids = []
    for _ in plan.steps:
        gv_camera.trigger()
        ids.append(gv_camera.next_frame(plan.frame_timeout_s).frame_id)
    stats = gv_camera.stats
    gv_camera.stop()
    assert (stats.frames_good, stats.frames_incomplete, stats.frames_missing, stats.buffers_unfilled) == (3, 0, 0, 1)
    assert [b - a for a, b in zip(ids, ids[1:])] == [1, 1]
