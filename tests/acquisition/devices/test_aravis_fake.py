"""AravisCamera on the in-process Aravis ``Fake`` interface (``Fake_1``) and its pure helpers.

Only the Fake interface is enabled here, so nothing is broadcast on the network.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import pytest

from msflash.acquisition.devices.aravis.camera_records import StrobeConfig, TriggerConfig
from msflash.acquisition.devices.aravis.discovery import list_devices, parse_interfaces
from msflash.acquisition.devices.aravis.pixel_layouts import (
    PIXEL_FORMATS,
    decode_pixels,
    frame_id_gap,
    is_zero_copy_format,
    view_pixels,
)
from msflash.acquisition.devices.aravis.profiles import match_profile
from msflash.acquisition.devices.camera import Camera
from msflash.acquisition.errors import CameraError, CameraNotFoundError, DroppedFrameError, FrameLostError
from msflash.acquisition.plan import CapturePlan
from tests.acquisition.support.fake_genicam import use_fake_genicam

pytestmark = pytest.mark.aravis


# -- pure helpers ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("previous", "current", "gap"),
    [
        (1, 2, 0),
        (10, 13, 2),
        (65534, 65535, 0),
        (65535, 1, 0),
        (65534, 1, 1),
        (65535, 2, 1),
        (7, 7, -1),
    ],
)
def test_frame_id_gap_wraps_at_16_bits_skipping_zero(aravis: ModuleType, previous: int, current: int, gap: int) -> None:
    assert frame_id_gap(previous, current) == gap


def test_frame_id_gap_without_wrap(aravis: ModuleType) -> None:
    assert frame_id_gap(2**40, 2**40 + 1, wrap=None, skip_zero=False) == 0
    assert frame_id_gap(5, 9, wrap=None, skip_zero=False) == 3


def test_decode_mono16_is_little_endian_owned_and_read_only(aravis: ModuleType) -> None:
    data = bytearray(np.arange(6, dtype="<u2").tobytes())
    pixels = decode_pixels(data, "Mono16", 3, 2)
    data[0] = 99  # the array must not alias the buffer it came from
    assert pixels.dtype == np.uint16 and pixels.shape == (2, 3)
    np.testing.assert_array_equal(pixels, np.arange(6).reshape(2, 3))
    assert not pixels.flags.writeable


def test_decode_bgr8_is_returned_as_rgb(aravis: ModuleType) -> None:
    pixels = decode_pixels(bytes([1, 2, 3, 4, 5, 6]), "BGR8", 2, 1)
    np.testing.assert_array_equal(pixels, [[[3, 2, 1], [6, 5, 4]]])


def test_decode_refuses_short_payload_and_unknown_format(aravis: ModuleType) -> None:
    with pytest.raises(CameraError, match="too short.*expected 8 bytes"):
        decode_pixels(bytes(7), "Mono16", 2, 2, where="camera X")
    with pytest.raises(CameraError, match="YUV422_8.*is not one msflash decodes"):
        decode_pixels(bytes(8), "YUV422_8", 2, 2)


def test_decode_and_view_route_packed_formats(aravis: ModuleType) -> None:
    # Mono12p 0x321, 0x654 (the packing itself is tested in test_pixel_formats.py)
    np.testing.assert_array_equal(decode_pixels(bytes([0x21, 0x43, 0x65]), "Mono12p", 2, 1), [[0x321, 0x654]])
    assert PIXEL_FORMATS["BayerRG12p"].cfa == "RGGB" and PIXEL_FORMATS["Mono10p"].bits == 10
    assert not is_zero_copy_format("Mono12Packed")
    with pytest.raises(CameraError, match="needs decoding"):
        view_pixels(np.zeros(3, np.uint8), "Mono12p", 2, 1)


def test_bayer_formats_carry_their_mosaic(aravis: ModuleType) -> None:
    assert PIXEL_FORMATS["BayerRG16"].cfa == "RGGB"
    assert PIXEL_FORMATS["BayerGB8"].cfa == "GBRG"
    assert PIXEL_FORMATS["Mono12"].bits == 12


def test_parse_interfaces_names_the_valid_ones(aravis: ModuleType) -> None:
    assert parse_interfaces("fake, GigE,fake") == ("fake", "gige")
    with pytest.raises(ValueError, match="unknown firewire; expected a subset of fake, gige, usb3"):
        parse_interfaces("fake,firewire")
    with pytest.raises(ValueError, match="empty"):
        parse_interfaces("")


def test_profiles_are_data_and_the_last_is_the_default(aravis: ModuleType) -> None:
    assert match_profile("FLIR", "Blackfly S BFS-U3-16S2M").user_outputs == (
        "UserOutput1",
        "UserOutput2",
        "UserOutput3",
    )
    assert match_profile("Acme", "X1").name == "generic"


# -- listing and opening --------------------------------------------------------------------


def test_list_devices_on_the_fake_interface_only(aravis: ModuleType) -> None:
    entries = list_devices("fake")
    assert [e.device_id for e in entries] == ["Fake_1"]
    assert entries[0].interface == "fake" and entries[0].to_dict()["model"] == "Fake"


def test_unknown_device_lists_what_was_found(aravis: ModuleType) -> None:
    with pytest.raises(CameraNotFoundError, match=r"'SN999'.*not found on fake \(found: Fake_1"):
        aravis.AravisCamera("SN999", interfaces="fake")


def test_ip_address_needs_the_gige_interface(aravis: ModuleType) -> None:
    with pytest.raises(CameraNotFoundError, match="expected 'gige' in the interfaces"):
        aravis.AravisCamera("127.0.0.1", interfaces="fake")


def test_open_by_serial_and_release_allows_reopening(aravis: ModuleType) -> None:
    use_fake_genicam(None)
    first = aravis.AravisCamera("1", interfaces="fake")  # Fake_1's serial number is "1"
    assert first.info.serial == "1"
    first.close()
    first.close()  # idempotent
    with pytest.raises(CameraError, match="closed"):
        first.get_feature("Width")
    with aravis.AravisCamera("Fake_1", interfaces="fake") as again:
        assert again.info.model == "Fake"


# -- settings -------------------------------------------------------------------------------


def test_is_a_camera_and_reports_its_encoding(fake_camera: Any) -> None:
    assert isinstance(fake_camera, Camera)
    info = fake_camera.info
    assert (info.vendor, info.model, info.pixel_format) == ("Aravis", "Fake", "Mono16")
    assert (info.width, info.height, info.cfa) == (320, 240, None)
    assert (info.black_level, info.white_level) == (0.0, 65535.0)
    assert info.extra["interface"] == "fake" and info.extra["exposure_feature"] == "ExposureTimeAbs"


def test_access_and_range_checks_are_enabled(fake_camera: Any) -> None:
    with pytest.raises(CameraError, match=r"camera Fake \(serial 1\).*SensorWidth.*read only"):
        fake_camera.set_feature("SensorWidth", 64)
    with pytest.raises(CameraError, match=r"camera Fake \(serial 1\).*Width=99999.*maximum"):
        fake_camera.set_roi(0, 0, 99999, 10)


def test_roi_is_read_back(fake_camera: Any) -> None:
    assert fake_camera.set_roi(16, 8, 64, 32) == (16, 8, 64, 32)
    assert fake_camera.get_feature("OffsetX") == 16


def test_wrong_pixel_format_names_camera_and_feature(fake_camera: Any) -> None:
    with pytest.raises(
        CameraError,
        match=r"camera Fake \(serial 1\): PixelFormat 'BayerRG16' is not "
        r"offered.*expected one of .*Mono16",
    ):
        fake_camera.set_pixel_format("BayerRG16")
    with pytest.raises(
        CameraError, match=r"camera Fake \(serial 1\): pixel format 'YUV422_8' is not one msflash decodes"
    ):
        fake_camera.set_pixel_format("YUV422_8")


def test_missing_line_features_name_camera_and_feature(aravis: ModuleType, fake_camera: Any) -> None:
    with pytest.raises(CameraError, match=r"camera Fake \(serial 1\): has no feature LineSelector"):
        fake_camera.configure_strobe(StrobeConfig(line="Line1"))
    with pytest.raises(CameraError, match="has no feature UserOutputSelector"):
        fake_camera.set_user_output(0, True)
    with pytest.raises(CameraError, match="has no feature TriggerDelay"):
        fake_camera.configure_trigger(TriggerConfig(mode="line", line="Line0", delay_us=10.0))


def test_camera_paced_plan_needs_a_strobe(fake_camera: Any) -> None:
    plan = CapturePlan.single([1.0], 1000.0, trigger="camera")
    with pytest.raises(CameraError, match="camera-paced plan needs a strobe"):
        fake_camera.prepare(plan)


def test_exposure_falls_back_to_exposure_time_abs_and_is_read_back(fake_camera: Any) -> None:
    assert fake_camera.set_exposure_us(2500.0) == 2500.0
    assert fake_camera.get_feature("ExposureTimeAbs") == 2500.0


def test_sfnc_xml_gives_sfnc_names_and_integer_exposure_is_recorded(sfnc_fake_camera: Any) -> None:
    cam = sfnc_fake_camera
    assert cam.settings.exposure_feature == "ExposureTime" and cam.settings.gain_feature == "Gain"
    assert cam.set_exposure_us(1234.6) == 1235.0  # the fake's register holds whole microseconds
    assert cam.set_gain(2.0) == pytest.approx(2.0, rel=1e-3)  # 6.02 dB in 0.01 dB steps
    assert cam.gain_db == pytest.approx(6.02)
    assert cam.user_outputs() == ("UserOutput0", "UserOutput1", "UserOutput2")


# -- acquisition ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pixel_format", "shape", "dtype", "cfa", "white"),
    [
        ("Mono8", (48, 64), np.uint8, None, 255.0),
        ("Mono16", (48, 64), np.uint16, None, 65535.0),
        ("RGB8", (48, 64, 3), np.uint8, None, 255.0),
        ("BayerRG8", (48, 64), np.uint8, "RGGB", 255.0),
    ],
)
def test_pixel_formats_arrive_as_arrays(
    aravis: ModuleType, pixel_format: str, shape: tuple[int, ...], dtype: type, cfa: str | None, white: float
) -> None:
    use_fake_genicam(None)
    with aravis.AravisCamera("Fake_1", interfaces="fake", pixel_format=pixel_format, roi=(0, 0, 64, 48)) as cam:
        assert (cam.info.cfa, cam.info.white_level) == (cfa, white)
        cam.prepare(CapturePlan.single([0.0], 1000.0))
        cam.start()
        cam.trigger()
        frame = cam.next_frame(5.0)
        cam.stop()
    assert frame.pixels.shape == shape and frame.pixels.dtype == dtype
    assert not frame.pixels.flags.writeable
    assert frame.pixels.flags.c_contiguous


def test_sequence_records_each_steps_exposure_and_keeps_ids_consecutive(fake_camera: Any) -> None:
    plan = CapturePlan.ambient_then_each_led(3, 4000.0, led_exposures_us=[1000.0, 2000.0, 3000.0])
    fake_camera.prepare(plan)
    fake_camera.start()
    frames = []
    for _ in plan.steps:
        fake_camera.trigger()  # Fake_1 ignores triggers: frames follow its clock
        frames.append(fake_camera.next_frame(plan.frame_timeout_s + 2.0))
    fake_camera.stop()
    fake_camera.stop()  # idempotent
    assert [f.exposure_us for f in frames] == [4000.0, 1000.0, 2000.0, 3000.0]
    assert all(f.gain == 1.0 for f in frames)
    ids = [f.frame_id for f in frames]
    assert all(b - a == 1 for a, b in zip(ids, ids[1:]))
    stats = fake_camera.stats
    assert (stats.frames_good, stats.frames_incomplete, stats.frames_missing) == (4, 0, 0)
    assert stats.n_buffers == len(plan.steps) + 4


def test_frame_lost_error_is_a_dropped_frame(aravis: ModuleType) -> None:
    assert issubclass(FrameLostError, DroppedFrameError)
    assert issubclass(FrameLostError, CameraError)


def test_start_before_prepare_is_an_error(fake_camera: Any) -> None:
    with pytest.raises(CameraError, match="start\\(\\) before prepare\\(\\)"):
        fake_camera.start()


def test_control_lost_signal_becomes_a_clear_error_naming_the_step(fake_camera: Any) -> None:
    from msflash.acquisition.errors import CameraDisconnectedError

    plan = CapturePlan.ambient_then_each_led(2, 1000.0)
    fake_camera.prepare(plan)
    fake_camera.start()
    fake_camera.next_frame(5.0)
    fake_camera._on_control_lost(None)  # what Aravis's "control-lost" signal calls (Fake_1 never emits it)
    with pytest.raises(
        CameraDisconnectedError,
        match=r"camera Fake \(serial 1\): control lost before "
        r"step 1 'led:1'.*check power and cable",
    ):
        fake_camera.next_frame(5.0)
    with pytest.raises(CameraDisconnectedError, match="control of the device was lost"):
        fake_camera.set_exposure_us(2000.0)
    fake_camera.close()  # still releases everything
