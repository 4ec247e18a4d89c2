"""Reference loops for the camera bench: plain Aravis, no msflash layer (:func:`bare_aravis_run`).

The lab's (it measures the camera path; nothing in the product runs it); it uses the Aravis typelib
through :mod:`msflash.acquisition.devices.aravis.gi_typelib`, never ``gi`` itself."""

from __future__ import annotations

import logging
import random
import time
from dataclasses import dataclass

from msflash.acquisition.devices.aravis.buffers import BufferPool
from msflash.acquisition.devices.aravis.camera_records import (
    FrameTiming,
)
from msflash.acquisition.devices.aravis.discovery import (
    use_interfaces,
)
from msflash.acquisition.devices.aravis.gi_typelib import Aravis
from msflash.acquisition.devices.aravis.gv_stream import create_gv_stream
from msflash.acquisition.devices.aravis.pixel_layouts import (
    frame_id_gap,
)
from msflash.acquisition.errors import (
    CameraError,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TriggerTiming:
    """One software trigger and its frame, as a latency run times them (``CLOCK_REALTIME`` ns)."""

    sent_ns: int
    """Just before the trigger call."""
    triggered_ns: int
    """When the trigger call returned (the device acknowledged the TriggerSoftware write)."""
    frame: FrameTiming
    """The frame's stage times; ``delivered_ns`` is when the caller had it in hand."""


@dataclass(frozen=True)
class BareRun:
    """What a bare Aravis loop measured."""

    frames: int
    """Complete frames received (warm-up frames excluded)."""
    bad: int
    """Buffers with a status other than success."""
    missing: int
    """Frame ids skipped."""
    seconds: float
    """Wall time from the first to the last frame received."""
    timings: tuple[TriggerTiming, ...] = ()
    """Per trigger, its stage times (software-trigger runs only; warm-up frames excluded)."""


def bare_aravis_run(
    address: str,
    *,
    width: int,
    height: int,
    pixel_format: str,
    n_frames: int,
    software_trigger: bool,
    frame_rate_hz: float | None = None,
    n_buffers: int = 16,
    timeout_s: float = 2.0,
    dither_s: float = 0.0,
    warm_up_frames: int = 0,
) -> BareRun:
    """The smallest correct Aravis loop on the GigE Vision camera at ``address``: pop, check, push.

    With ``software_trigger`` each frame is triggered and waited for (latency); otherwise the
    camera free-runs at ``frame_rate_hz`` and the loop measures throughput. It is the baseline
    the bench compares :class:`AravisCamera` against; it never copies pixels, and its buffers,
    like AravisCamera's, use pre-faulted memory. ``dither_s`` waits a random time up to that long
    before each trigger, and the first ``warm_up_frames`` frames are received but not counted or
    timed (see ``bench_camera`` for why both matter on the fake).
    """
    use_interfaces(("gige",))
    camera = Aravis.Camera.new(address)
    pool: BufferPool | None = None
    try:
        device = camera.get_device()
        camera.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
        camera.set_region(0, 0, width, height)
        camera.set_pixel_format_from_string(pixel_format)
        if software_trigger:
            camera.set_trigger("Software")
        else:
            device.set_string_feature_value("TriggerSelector", "FrameStart")
            device.set_string_feature_value("TriggerMode", "Off")
            if frame_rate_hz is not None:
                camera.set_frame_rate(frame_rate_hz)
        payload = int(camera.get_payload())
        stream = create_gv_stream(camera, payload)  # as AravisCamera's
        pool = BufferPool(stream, payload, zero_copy=True)  # buffers only pushed back
        pool.fill(n_buffers)
        camera.start_acquisition()
        frames = bad = missing = 0
        previous: int | None = None
        timings: list[TriggerTiming] = []
        first = last = time.perf_counter()
        try:
            for index in range(-warm_up_frames, n_frames):
                if dither_s > 0:
                    time.sleep(random.uniform(0.0, dither_s))
                sent = triggered = time.time_ns()
                if software_trigger:
                    camera.software_trigger()
                    triggered = time.time_ns()
                buffer = stream.timeout_pop_buffer(int(timeout_s * 1e6))
                popped = time.time_ns()
                now = time.perf_counter()
                if buffer is None:
                    raise CameraError(
                        f"bare Aravis loop on {address}: no frame within {timeout_s} s; expected a streaming camera"
                    )
                try:
                    good = buffer.get_status() == Aravis.BufferStatus.SUCCESS
                    frame_id = int(buffer.get_frame_id())
                    stamps = int(buffer.get_timestamp()), int(buffer.get_system_timestamp())
                finally:
                    stream.push_buffer(buffer)
                delivered = time.time_ns()
                if index < 0:
                    previous = frame_id
                    continue
                frames, bad = frames + good, bad + (not good)
                if previous is not None:
                    missing += max(0, frame_id_gap(previous, frame_id))
                if index == 0:
                    first = now
                previous = frame_id
                last = now
                if software_trigger:
                    timings.append(TriggerTiming(sent, triggered, FrameTiming(*stamps, popped, delivered)))
        finally:
            camera.stop_acquisition()
        return BareRun(frames, bad, missing, last - first, tuple(timings))
    finally:
        if pool is not None:
            pool.release()  # the stream and its buffers go before their arrays
        stream = None  # noqa: F841 - release the stream before the camera
        camera = None  # noqa: F841
