"""AravisCamera over real GVCP/GVSP: the GigE Vision fake on 127.0.0.1 with msflash's SFNC XML.

What the app wrote is checked in the fake's registers (addresses from
``acquisition/genicam/fake_sfnc.xml``). The fake is opened by IP address only: no discovery.
"""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType
from typing import Any

import pytest

from msflash.acquisition.devices.aravis.buffers import Bad
from msflash.acquisition.devices.aravis.camera_records import StrobeConfig, TriggerConfig
from msflash.acquisition.devices.aravis.pixel_layouts import frame_id_gap
from msflash.acquisition.errors import CameraError, FrameLostError, FrameTimeoutError
from msflash.acquisition.plan import CapturePlan

pytestmark = pytest.mark.aravis

# Registers of fake_sfnc.xml (the fake's own ones and msflash's additions).
REG_EXPOSURE_US = 0x120
REG_TRIGGER_MODE = 0x300  # FrameStart; AcquisitionStart is +0x20
REG_TRIGGER_SOURCE = 0x304
REG_TRIGGER_ACTIVATION = 0x308
REG_GAIN_CENTI_DB = 0x4004
REG_TRIGGER_DELAY_US = 0x400C
REG_LINE_SELECTOR = 0x4010
REG_LINE_MODE = 0x4100  # + 0x10 per line
REG_LINE_SOURCE = 0x4108
REG_USER_OUTPUT_VALUE = 0x4200  # + 4 per output


def _run(camera: Any, plan: CapturePlan) -> list[Any]:
    camera.prepare(plan)
    camera.start()
    frames = []
    for _ in plan.steps:
        camera.trigger()
        frames.append(camera.next_frame(plan.frame_timeout_s))
    camera.stop()
    return frames


def test_opens_by_address_and_identifies_the_fake(gv_camera: Any) -> None:
    info = gv_camera.info
    assert (info.vendor, info.model, info.serial) == ("Aravis", "Fake", "MSFTEST1")
    assert info.extra["interface"] == "gige" and info.extra["address"] == "127.0.0.1"
    assert info.extra["exposure_feature"] == "ExposureTime" and info.extra["gain_feature"] == "Gain"


def test_software_plan_writes_trigger_exposure_gain_and_strobe(aravis: ModuleType, gv_fake: Any) -> None:
    strobe = StrobeConfig(line="Line1", source="ExposureActive")
    plan = CapturePlan.ambient_then_each_led(2, 2500.4, gain=2.0)
    with aravis.AravisCamera(
        gv_fake.address, interfaces="gige", pixel_format="Mono16", roi=(0, 0, 64, 48), strobe=strobe
    ) as camera:
        frames = _run(camera, plan)
        assert camera.settings.strobe == strobe
    assert gv_fake.read_register(REG_TRIGGER_MODE) == 1  # On
    assert gv_fake.read_register(REG_TRIGGER_MODE + 0x20) == 0  # AcquisitionStart trigger off
    assert gv_fake.read_register(REG_TRIGGER_SOURCE) == 1  # Software
    assert gv_fake.read_register(REG_EXPOSURE_US) == 2500
    assert gv_fake.read_register(REG_GAIN_CENTI_DB) == 602  # 20 log10(2) dB
    assert gv_fake.read_register(REG_LINE_SELECTOR) == 1  # Line1
    assert gv_fake.read_register(REG_LINE_MODE + 0x10) == 1  # Output
    assert gv_fake.read_register(REG_LINE_SOURCE + 0x10) == 1  # ExposureActive
    # Recorded as actually set: whole microseconds, 0.01 dB steps.
    assert {f.exposure_us for f in frames} == {2500.0}
    assert all(f.gain == pytest.approx(10 ** (6.02 / 20)) for f in frames)
    assert all(f.pixels.shape == (48, 64) for f in frames)


def test_per_step_exposures_follow_the_plan(gv_camera: Any, gv_fake: Any) -> None:
    plan = CapturePlan.ambient_then_each_led(3, 800.0, led_exposures_us=[1000.0, 2000.0, 3000.0])
    frames = _run(gv_camera, plan)
    assert [f.exposure_us for f in frames] == [800.0, 1000.0, 2000.0, 3000.0]
    assert gv_fake.read_register(REG_EXPOSURE_US) == 3000
    assert gv_camera.stats.frames_good == 4


def test_line_trigger_with_activation_and_delay(aravis: ModuleType, gv_fake: Any) -> None:
    line = TriggerConfig(mode="line", line="Line1", activation="FallingEdge", delay_us=150.0)
    plan = CapturePlan.single([1.0, 0.0], 1000.0, trigger="booth")
    with aravis.AravisCamera(gv_fake.address, interfaces="gige", roi=(0, 0, 32, 32), line_trigger=line) as camera:
        camera.prepare(plan)
        assert camera.settings.trigger == line
        camera.start()
        camera.trigger()  # no-op: the booth pulses the line
        # Nobody pulses Line1 here: the wait ends with an error naming the step.
        with pytest.raises(
            FrameTimeoutError,
            match=r"camera Fake \(serial MSFTEST1\): no frame for step 0 "
            r"'flash' within 0.2 s",
        ):
            camera.next_frame(0.2)
    assert gv_fake.read_register(REG_TRIGGER_MODE) == 1
    assert gv_fake.read_register(REG_TRIGGER_SOURCE) == 2  # Line1
    assert gv_fake.read_register(REG_TRIGGER_ACTIVATION) == 1  # FallingEdge
    assert gv_fake.read_register(REG_TRIGGER_DELAY_US) == 150


def test_unknown_line_names_the_entries(aravis: ModuleType, gv_camera: Any) -> None:
    with pytest.raises(CameraError, match=r"TriggerSource has no entry 'Line7'; expected one of Line0, Software"):
        gv_camera.configure_trigger(TriggerConfig(mode="line", line="Line7"))
    with pytest.raises(CameraError, match=r"LineSource has no entry 'Timer0Active'"):
        gv_camera.configure_strobe(StrobeConfig(line="Line2", source="Timer0Active"))


def test_user_outputs_by_position_and_name(gv_camera: Any, gv_fake: Any) -> None:
    gv_camera.set_user_output(2, True)
    assert gv_fake.read_register(REG_USER_OUTPUT_VALUE + 8) == 1
    gv_camera.set_user_output("UserOutput2", False)
    assert gv_fake.read_register(REG_USER_OUTPUT_VALUE + 8) == 0
    with pytest.raises(CameraError, match="user output 3 out of range; expected 0..2"):
        gv_camera.set_user_output(3, True)


def test_counter_and_chunk_features_are_real_nodes(gv_camera: Any) -> None:
    assert gv_camera.set_feature("CounterSelector", "Counter1") == "Counter1"
    assert gv_camera.set_feature("CounterEventSource", "FrameStart") == "FrameStart"
    assert gv_camera.set_feature("ChunkSelector", "ExposureTime") == "ExposureTime"
    assert gv_camera.set_feature("ChunkEnable", True) is True
    with pytest.raises(CameraError, match="LineStatus.*read only"):
        gv_camera.set_feature("LineStatus", True)


def test_wrong_pixel_format_names_camera_and_feature(gv_camera: Any) -> None:
    with pytest.raises(CameraError, match=r"camera Fake \(serial MSFTEST1\): PixelFormat 'Mono12' is not offered"):
        gv_camera.set_pixel_format("Mono12")


def test_frame_ids_continue_across_the_16_bit_wrap(aravis: ModuleType, gv_camera: Any) -> None:
    # The fake starts its block ids at 65401, so 140 frames cross 65535 -> 1 (0 is never sent).
    plan = CapturePlan(tuple(CapturePlan.single([0.0], 100.0).steps) * 140)
    frames = _run(gv_camera, plan)
    ids = [f.frame_id for f in frames]
    assert any(b < a for a, b in zip(ids, ids[1:])), f"no wrap seen in ids {ids[0]}..{ids[-1]}"
    assert 0 not in ids
    stats = gv_camera.stats
    assert (stats.frames_good, stats.frames_incomplete, stats.frames_missing) == (140, 0, 0)


def test_lossy_link_reports_incomplete_frames_and_never_returns_them(
    aravis: ModuleType, gv_fake_process: Callable[..., Any]
) -> None:
    gv_fake_process(serial="MSFLOSSY", lost_per_thousand=20)  # 2 % of GVSP packets dropped
    n = 24
    plan = CapturePlan(tuple(CapturePlan.single([0.0], 100.0).steps) * n)
    good, lost = [], []
    with aravis.AravisCamera("127.0.0.1", interfaces="gige", roi=(0, 0, 256, 256)) as camera:
        camera.prepare(plan)
        camera.start()
        for _ in range(n):
            camera.trigger()
            try:
                good.append(camera.next_frame(plan.frame_timeout_s + 2.0))
            except FrameLostError as err:
                lost.append(err)
        camera.stop()
        stats = camera.stats
        # A stream that lost frames is released, not kept for the next acquisition: Aravis may
        # still hold a partial frame of it (docs/steady-tests.md §1).
        assert camera.pool_arrays == (0, 0)
        camera.prepare(plan)  # a fresh stream, which delivers
        camera.start()
        delivered = 0
        for _ in range(n):
            camera.trigger()
            try:
                camera.next_frame(plan.frame_timeout_s + 2.0)
                delivered += 1
            except FrameLostError:
                pass
        camera.stop()
        assert delivered > 0
    # About 45 packets a frame: with 2 % loss most frames lose one, some arrive whole.
    assert lost, "no incomplete frame on a link dropping 2 % of packets"
    assert stats.frames_incomplete + stats.frames_missing >= len(lost) > 0
    assert stats.frames_good == len(good)
    assert sum(stats.statuses.values()) == stats.frames_incomplete
    assert all("serial MSFLOSSY" in str(err) for err in lost)
    assert all(frame.pixels.shape == (256, 256) for frame in good)


def test_a_frame_aravis_could_not_identify_is_taken_as_the_next_one(aravis: ModuleType, gv_camera: Any) -> None:
    """Aravis reports some broken frames with block id 0 (never sent on GigE Vision): that frame
    is reported incomplete, without counting 65 535 ids as missing, and the good frame after it is
    delivered (it was refused as '… frame(s) lost before' it)."""
    plan = CapturePlan(tuple(CapturePlan.single([0.0], 100.0).steps) * 3)
    gv_camera.prepare(plan)
    gv_camera.start()
    gv_camera.trigger()
    first = gv_camera.next_frame(plan.frame_timeout_s)
    gv_camera.trigger()
    arrived = gv_camera._queue.get(timeout=plan.frame_timeout_s)  # the fake's second frame ...
    assert arrived.frame_id != 0
    gv_camera._queue.put(Bad(0, "timeout"))  # ... as Aravis delivers one it could not identify
    with pytest.raises(FrameLostError, match="frame 0 for step 1 'flash' arrived incomplete"):
        gv_camera.next_frame(plan.frame_timeout_s)
    gv_camera.trigger()
    third = gv_camera.next_frame(plan.frame_timeout_s)
    assert frame_id_gap(first.frame_id, third.frame_id) == 1
    stats = gv_camera.stats
    assert (stats.frames_good, stats.frames_incomplete, stats.frames_missing) == (2, 1, 0)
    gv_camera.stop()


def test_close_releases_control_for_the_next_controller(aravis: ModuleType, gv_fake: Any) -> None:
    first = aravis.AravisCamera(gv_fake.address, interfaces="gige")
    first.set_exposure_us(1500.0)
    first.close()
    # GigE Vision grants one controller at a time: writing works only if `first` let go.
    with aravis.AravisCamera(gv_fake.address, interfaces="gige") as second:
        assert second.set_exposure_us(1700.0) == 1700.0
    assert gv_fake.read_register(REG_EXPOSURE_US) == 1700
