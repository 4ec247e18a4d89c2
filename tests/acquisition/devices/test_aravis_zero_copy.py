"""Zero-copy frames: Aravis writes each frame into an array msflash allocated, and that array is the frame.

The frames are checked against the test pattern the Aravis fakes draw (``arvfakecamera.c``,
0.8.26: at exposure 10 ms and gain 0 a Mono16 pixel is ``256 (x + y + frame id) mod 65535`` and a
Mono8 pixel ``(x + y + frame id) mod 255``), on both delivery paths. GigE Vision: the fake on
127.0.0.1 opened by address; otherwise the in-process ``Fake`` interface. Nothing is broadcast.
"""

from __future__ import annotations

import gc
import weakref
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from msflash.acquisition.devices.aravis.buffers import ZERO_COPY_PROTOCOLS
from msflash.acquisition.devices.aravis.pixel_layouts import decode_pixels, is_zero_copy_format, view_pixels
from msflash.acquisition.errors import CameraDisconnectedError, CameraError
from msflash.acquisition.plan import CapturePlan
from tests.acquisition.support.fake_genicam import use_fake_genicam

pytestmark = pytest.mark.aravis

WIDTH, HEIGHT = 64, 48
EXPOSURE_US = 10_000.0
"""The fakes scale their pattern by 1 + gain + log10(exposure / 10 ms): 1 here."""


def _pattern(pixel_format: str, frame_id: int) -> np.ndarray:
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    if pixel_format == "Mono16":
        return ((256 * (x + y + frame_id)) % 65535).astype(np.uint16)
    return ((x + y + frame_id) % 255).astype(np.uint8)


def _plan(n: int) -> CapturePlan:
    return CapturePlan(tuple(CapturePlan.single([0.0], EXPOSURE_US).steps) * n)


def _payload_array(pixels: np.ndarray) -> np.ndarray | None:
    """The array owning a zero-copy frame's memory (None for a copied frame, whose memory is ``bytes``)."""
    owner: Any = pixels
    while isinstance(owner, np.ndarray) and not owner.flags.owndata:
        owner = owner.base
    return owner if isinstance(owner, np.ndarray) else None


def _gv_camera(aravis: ModuleType, gv_fake: Any, **options: Any) -> Any:
    """AravisCamera on the GigE Vision fake by address, Mono16 64x48."""
    return aravis.AravisCamera(
        gv_fake.address, interfaces="gige", pixel_format="Mono16", roi=(0, 0, WIDTH, HEIGHT), **options
    )


def _frames(camera: Any, n: int, timeout_s: float = 5.0) -> list[Any]:
    frames = []
    for _ in range(n):
        camera.trigger()
        frames.append(camera.next_frame(timeout_s))
    return frames


# -- pure helpers ---------------------------------------------------------------------------


def test_view_pixels_matches_decode_pixels_without_copying(aravis: ModuleType) -> None:
    payload = np.arange(40, dtype=np.uint8)  # 36 bytes of image, 4 bytes of trailing chunk data
    for pixel_format, shape in (("Mono16", (3, 6)), ("RGB8", (3, 4, 3)), ("BayerGR8", (6, 6))):
        width, height = shape[1], shape[0]
        view = view_pixels(payload, pixel_format, width, height)
        decoded = decode_pixels(payload.tobytes(), pixel_format, width, height)
        assert view.shape == decoded.shape == shape and view.dtype == decoded.dtype
        np.testing.assert_array_equal(view, decoded)
        assert np.shares_memory(view, payload) and not view.flags.writeable and view.flags.c_contiguous


def test_view_pixels_refuses_reordered_formats_and_short_payloads(aravis: ModuleType) -> None:
    assert not is_zero_copy_format("BGR8") and not is_zero_copy_format("Mono12Packed")
    assert "usb3" not in ZERO_COPY_PROTOCOLS
    with pytest.raises(CameraError, match="camera X: pixel format 'BGR8' needs decoding"):
        view_pixels(np.zeros(6, np.uint8), "BGR8", 2, 1, where="camera X")
    with pytest.raises(CameraError, match="camera X: payload of 7 bytes is too short.*expected 8 bytes"):
        view_pixels(np.zeros(7, np.uint8), "Mono16", 2, 2, where="camera X")


# -- the GigE Vision fake -------------------------------------------------------------------


@pytest.mark.parametrize("zero_copy", [True, False])
def test_frames_hold_the_fakes_pattern_on_both_paths(aravis: ModuleType, gv_fake: Any, zero_copy: bool) -> None:
    with _gv_camera(aravis, gv_fake, zero_copy=zero_copy) as camera:
        plan = _plan(4)
        camera.prepare(plan)
        n_buffers = len(plan.steps) + 4
        assert camera.pool_arrays == ((n_buffers, len(plan.steps)) if zero_copy else (0, 0))
        camera.start()
        frames = _frames(camera, 4)
        camera.stop()
    for frame in frames:
        np.testing.assert_array_equal(frame.pixels, _pattern("Mono16", frame.frame_id))
        assert frame.pixels.dtype == np.uint16 and not frame.pixels.flags.writeable
        payload = _payload_array(frame.pixels)
        assert (payload is not None) == zero_copy
        if payload is not None:
            assert payload.nbytes >= WIDTH * HEIGHT * 2 and payload.flags.owndata


def test_successive_frames_never_share_memory_nor_change(aravis: ModuleType, gv_fake: Any) -> None:
    """Every frame is its own array, and later frames (into buffers refilled by Aravis) leave it alone."""
    with _gv_camera(aravis, gv_fake, extra_buffers=1) as camera:
        camera.prepare(_plan(2))  # a pool of 3 buffers, 2 spares: 14 frames cycle through it
        camera.start()
        frames = _frames(camera, 14)
        camera.stop()
    ids = [f.frame_id for f in frames]
    assert len(set(ids)) == len(ids)
    for i, a in enumerate(frames):
        np.testing.assert_array_equal(a.pixels, _pattern("Mono16", a.frame_id))
        for b in frames[i + 1 :]:
            assert not np.shares_memory(a.pixels, b.pixels)


def test_a_run_longer_than_the_pool_keeps_it_whole_and_holds_no_frame(aravis: ModuleType, gv_fake: Any) -> None:
    """Beyond the spares the popping thread allocates each replacement; the camera's arrays stay
    as many as its buffers, and frames the caller drops are freed."""
    n_frames = 40
    with _gv_camera(aravis, gv_fake, extra_buffers=1) as camera:
        plan = _plan(3)
        camera.prepare(plan)
        n_buffers = len(plan.steps) + 1
        assert camera.pool_arrays == (n_buffers, 3)
        camera.start()
        dropped: list[weakref.ref[np.ndarray]] = []
        held = []
        for _ in range(n_frames):
            camera.trigger()
            frame = camera.next_frame(5.0)
            np.testing.assert_array_equal(frame.pixels, _pattern("Mono16", frame.frame_id))
            payload = _payload_array(frame.pixels)
            assert payload is not None
            dropped.append(weakref.ref(payload))
            held.append(camera.pool_arrays)
            del frame, payload
        camera.stop()
        stats = camera.stats
        assert (stats.frames_good, stats.frames_incomplete, stats.frames_missing) == (n_frames, 0, 0)
        # The pool never shrinks: each handed-out buffer is replaced before the next frame is popped
        # (the next trigger comes after the frame is in hand, so the replacement may still be on its way).
        assert all(in_stream >= n_buffers - 1 for in_stream, _ in held)
        assert camera.pool_arrays[0] == n_buffers
        assert [spares for _, spares in held][-1] == 0 and max(s for _, s in held) <= 3
        gc.collect()
        assert all(ref() is None for ref in dropped), "the camera kept frames the caller dropped"
    assert camera.pool_arrays == (0, 0)


def test_stop_and_prepare_reuse_the_stream_and_its_arrays(aravis: ModuleType, gv_fake: Any) -> None:
    with _gv_camera(aravis, gv_fake) as camera:
        plan = _plan(3)
        runs = []
        for _ in range(2):
            camera.prepare(plan)
            assert camera.pool_arrays == (len(plan.steps) + 4, 3)  # spares topped up again
            camera.start()
            runs.append(_frames(camera, 3))
            camera.stop()
    for frames in runs:
        for frame in frames:
            np.testing.assert_array_equal(frame.pixels, _pattern("Mono16", frame.frame_id))


def test_close_with_frames_in_flight_releases_everything(aravis: ModuleType, gv_fake: Any) -> None:
    camera = _gv_camera(aravis, gv_fake)
    plan = _plan(6)
    camera.prepare(plan)
    camera.start()
    kept = _frames(camera, 2)
    for _ in range(4):  # triggered, never collected: queued or still being received at close
        camera.trigger()
    camera.close()
    assert camera.pool_arrays == (0, 0)
    for frame in kept:
        np.testing.assert_array_equal(frame.pixels, _pattern("Mono16", frame.frame_id))
    # The device was let go: another controller can take it and stream.
    with _gv_camera(aravis, gv_fake) as again:
        again.prepare(_plan(1))
        again.start()
        (frame,) = _frames(again, 1)
        np.testing.assert_array_equal(frame.pixels, _pattern("Mono16", frame.frame_id))


# -- the in-process Fake interface -------------------------------------------------------------


def test_control_lost_releases_the_pool_and_keeps_delivered_frames(aravis: ModuleType) -> None:
    use_fake_genicam(None)
    with aravis.AravisCamera("Fake_1", interfaces="fake", pixel_format="Mono8", roi=(0, 0, WIDTH, HEIGHT)) as camera:
        camera.prepare(_plan(3))
        camera.start()
        frame = camera.next_frame(5.0)  # Fake_1 follows its own clock, triggers or not
        camera._on_control_lost(None)  # what Aravis's "control-lost" signal calls (Fake_1 never emits it)
        with pytest.raises(CameraDisconnectedError, match="control lost before step 1"):
            camera.next_frame(5.0)
        camera.stop()  # control lost: the stream is released, not kept for the next prepare
        assert camera.pool_arrays == (0, 0)
    assert _payload_array(frame.pixels) is not None
    np.testing.assert_array_equal(frame.pixels, _pattern("Mono8", frame.frame_id))
