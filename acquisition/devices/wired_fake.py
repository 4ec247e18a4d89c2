"""The ``aravis-fake`` rig's camera: the GigE Vision fake with the trigger wires it lacks, and a scene."""

from __future__ import annotations

import collections
import dataclasses
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from msflash.acquisition.devices.aravis.pixel_layouts import PIXEL_FORMATS
from msflash.acquisition.devices.camera import CameraInfo, RawFrame
from msflash.acquisition.devices.image_format import BINNING_FEATURES, ImageFormat, ImageFormatRequest, ImageLimits
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.errors import CameraError, CameraSettingError, FrameLostError
from msflash.acquisition.plan import CapturePlan

log = logging.getLogger(__name__)


class TriggerLines(Protocol):
    """The booth's side of the wires the fake lacks (the booth emulator is one): the levels it holds
    now and its ExposureActive input."""

    @property
    def levels(self) -> tuple[float, ...]:
        """The LED levels the booth holds now."""
        ...

    def exposure_active(self, active: bool) -> None:
        """Drive the booth's ExposureActive input (camera master)."""
        ...


class WiredFakeCamera:
    """An ``AravisCamera`` on the GigE fake with the trigger wires the fake lacks, emulated, and a scene.

    The fake honours only software triggers and has no ExposureActive output, so:

    - every plan is prepared on the fake with software triggering;
    - booth master (``plan.trigger == "booth"``): :meth:`trigger` is a no-op and the emulator's
      trigger output calls :meth:`trigger_line`, which issues the software trigger;
    - camera master (``"camera"``): :meth:`trigger` raises the emulator's ExposureActive line and
      issues the software trigger; the frame's arrival lowers it (exposure over).

    The fake latches a software trigger in a register that its stream thread polls and clears
    (``TriggerSoftware`` at 0x30c, about 1 kHz): two triggers between polls make one frame. A real
    trigger input takes every edge, so booth pulses go through a queue and a thread that issues
    each software trigger only once the fake has acknowledged the previous one.

    **The scene** (``world`` given, the ``aravis-fake`` rig's default): Aravis does the streaming,
    features and triggering; the pixels of each frame it delivers are replaced by ``world``'s rendering
    (:meth:`SimulatedCamera.render`) under the booth's LED levels *at the moment that frame was
    triggered* (queued first-in first-out, one per issued trigger), with the exposure and gain the
    camera read back for that frame. (The fake's own generator cannot be given the scene:
    docs/aravis-facts.md.) Without ``world`` (the capture bench) frames are the fake's test pattern in
    the format it is set to (Mono16, or a Bayer, RGB … format: recorded as what that format means), blind to the
    LED levels.
    """

    TRIGGER_REGISTER = 0x30C
    """The fake's TriggerSoftware register (see ``genicam/fake_sfnc.xml``): 1 until the fake takes the trigger."""

    def __init__(
        self,
        camera: Any,
        emulator: TriggerLines,
        fake: Any = None,
        errors: list[BaseException] | None = None,
        world: SimulatedCamera | None = None,
        true_gain: Callable[[], float] | None = None,
    ) -> None:
        self.aravis = camera
        self.world = world
        """The scene's renderer, or None to keep the fake's test patterns."""
        self._true_gain = true_gain
        """The linear gain the twin's sensor applies now (its camera model's truth, from the fake's
        registers); None renders at the gain the camera read back for the frame."""
        self._emulator = emulator
        self._fake = fake
        self._errors = errors if errors is not None else []
        self._mode = "software"
        self._exposing = False
        self._pulses: queue.Queue[tuple[float, ...] | None] = queue.Queue()
        self._pulse_thread: threading.Thread | None = None
        self._pending: collections.deque[tuple[float, ...]] = collections.deque()
        self._pending_lock = threading.Lock()
        self._rendered_levels: list[tuple[float, ...]] = []
        self._first_timestamp_ns: int | None = None

    @property
    def suggested_exposure_us(self) -> float:
        """An exposure that suits the scene (the world's reference exposure), 10 ms for test patterns."""
        suggested = self.world.suggested_exposure_us if self.world is not None else None
        return float(suggested or 10_000.0)

    @property
    def sensor(self) -> Any:
        """The rendered sensor's model (noise, levels), or None for test patterns."""
        return self.world.sensor if self.world is not None else None

    @property
    def rendered_levels(self) -> tuple[tuple[float, ...], ...]:
        """The LED levels each frame delivered so far was rendered under, in order."""
        with self._pending_lock:
            return tuple(self._rendered_levels)

    @property
    def info(self) -> CameraInfo:
        """The fake's identity and pixel format (its mosaic layout and depth as the format means them); with a scene,
        the rendered sensor's black and white levels."""
        info = self.aravis.info
        if self.world is None:  # the fake's own test pattern, in whatever format it is set to
            return info
        black, white = self.world.readout.levels(self.world.sensor.black_level, self.world.sensor.white_level)
        return dataclasses.replace(
            info,
            black_level=black,
            white_level=white,
            extra={**info.extra, "pixels": f"rendered scene ({self.world.info.model})"},
        )

    # -- the image format: the fake's own features and limits; the scene follows its ROI and depth --
    @property
    def image_format(self) -> ImageFormat:
        """The fake's ROI, binning and pixel format, read back."""
        return self.aravis.image_format

    def image_limits(self) -> ImageLimits:
        """The fake's limits; with a scene, its binning locked (the fake's frames keep their size when it bins)."""
        limits = self.aravis.image_limits()
        if self.world is None:
            return limits
        why = "the Aravis fake keeps its frame size when it bins, so the rendered scene cannot follow; expected 1×1"
        locked = {name: why for name in BINNING_FEATURES if name in limits.features}
        return dataclasses.replace(limits, locked={**limits.locked, **locked})

    def set_image_format(self, request: ImageFormatRequest) -> ImageFormat:
        """Write ``request`` to the fake (between acquisitions); with a scene, refuse what the scene cannot follow
        (binning, a layout other than its mosaic's, an ROI outside it) and read the scene out at the new ROI
        and depth."""
        world = self.world
        if world is not None:
            limits = self.image_limits()
            if request.binning is not None and tuple(request.binning) != self.image_format.binning:
                limits.check_binning(request.binning)
            layout = PIXEL_FORMATS.get(request.pixel_format or "")
            if request.pixel_format is not None and (layout is None or layout.cfa != world.sensor.cfa):
                same = [name for name, entry in PIXEL_FORMATS.items() if entry.cfa == world.sensor.cfa]
                offered = [name for name in limits.features["PixelFormat"].entries if name in same]
                raise CameraSettingError(
                    f"aravis-fake: pixel format {request.pixel_format}: the rendered scene is a "
                    f"{world.sensor.cfa} mosaic; expected one of {', '.join(offered)}"
                )
            height, width = world.readout.sensor_shape
            x, y, w, h = request.roi or (0, 0, 1, 1)
            if x + w > width or y + h > height:
                raise CameraSettingError(
                    f"aravis-fake: ROI {x},{y},{w},{h}: outside the rendered scene ({width} × {height}); "
                    "expected offset + size within it"
                )
        image = self.aravis.set_image_format(request)
        if world is not None:
            world.readout = dataclasses.replace(world.readout, roi=image.roi, pixel_format=image.pixel_format)
        return image

    @property
    def exposure_range_us(self) -> tuple[float, float] | None:
        """The fake's exposure limits in microseconds (what ``--exposure`` is checked against)."""
        return self.aravis.exposure_range_us

    def check_step_gain(self, gain: float) -> None:
        """Refuse a plan step's linear ``gain`` the camera cannot take (``AravisCamera.check_step_gain``)."""
        self.aravis.check_step_gain(gain)

    def prepare(self, plan: CapturePlan) -> None:
        """Prepare the fake for ``plan`` with software triggering whatever the sync mode."""
        self._mode = plan.trigger
        self.aravis.prepare(dataclasses.replace(plan, trigger="software"))

    def update_plan(self, plan: CapturePlan, index: int) -> None:
        """Take ``plan`` with step ``index`` changed (software triggered, as prepared)."""
        self.aravis.update_plan(dataclasses.replace(plan, trigger="software"), index)

    @property
    def readout_skew_us(self) -> float:
        """The fake's (0: a global shutter)."""
        return float(self.aravis.readout_skew_us)

    def start(self) -> None:
        """Start acquisition (and, for booth-paced plans, the thread that turns pulses into triggers)."""
        self._exposing = False
        with self._pending_lock:
            self._pending.clear()
        self._forget_latched_trigger()
        self.aravis.start()
        if self._mode == "booth":
            self._pulses = queue.Queue()
            self._pulse_thread = threading.Thread(
                target=self._issue_pulses, name="aravis-fake trigger line", daemon=True
            )
            self._pulse_thread.start()

    def _issue_pulses(self) -> None:
        while (levels := self._pulses.get()) is not None:
            try:
                self._wait_trigger_taken()
                self._software_trigger(levels)
            except Exception as err:  # noqa: BLE001 - the capture sees the missing frame
                log.error("aravis-fake trigger line: %s", err)
                self._errors.append(err)

    def _forget_latched_trigger(self) -> None:
        """Clear a software trigger the fake latched but has not taken (before each acquisition starts).

        A real camera ignores triggers while it is not acquiring; the fake keeps the last one in
        its register and takes it when the next acquisition starts, sending a frame nobody triggered.
        """
        if self._fake is not None:
            self._fake.write_register(self.TRIGGER_REGISTER, 0)

    def _wait_trigger_taken(self, timeout_s: float = 1.0) -> None:
        if self._fake is None:
            return
        deadline = time.monotonic() + timeout_s
        while self._fake.read_register(self.TRIGGER_REGISTER) != 0 and time.monotonic() < deadline:
            time.sleep(0.0005)

    def _software_trigger(self, levels: tuple[float, ...]) -> None:
        """Issue the fake's software trigger for a frame to be rendered under ``levels``.

        The levels are queued first: the frame may arrive (on another thread) before the trigger
        call returns. A trigger that fails takes its levels back (only one thread triggers at a time).
        """
        with self._pending_lock:
            self._pending.append(levels)
        try:
            self.aravis.trigger()
        except BaseException:
            with self._pending_lock:
                self._pending.pop()
            raise

    def trigger(self) -> None:
        """Host-paced: software trigger; camera master: ExposureActive high, then software trigger."""
        if self._mode == "booth":
            return
        if self._mode == "camera":
            self._emulator.exposure_active(True)
            self._exposing = True
        self._software_trigger(self._emulator.levels)

    def trigger_line(self) -> None:
        """The booth pulsed the trigger input: queue a software trigger with the levels it exposes."""
        self._pulses.put(self._emulator.levels)

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The next frame, (H, W); in camera master the exposure line falls when it arrives.

        With a scene, its pixels are the scene rendered under the levels of its trigger, at the
        exposure the camera reports for it and the gain the twin's sensor applies (its camera
        model's truth, read from the fake's registers: what msflash believes it set is not asked).
        """
        try:
            frame = self.aravis.next_frame(timeout_s)
        except FrameLostError:
            self._take_levels()  # that trigger's frame is gone
            raise
        finally:
            if self._exposing:
                self._exposing = False
                self._emulator.exposure_active(False)
        levels = self._take_levels()
        if self.world is None:
            return frame
        if levels is None:
            raise CameraError(
                f"aravis-fake: frame {frame.frame_id} arrived with no trigger issued for it; expected "
                "one frame per trigger"
            )
        gain = self._true_gain() if self._true_gain is not None else frame.gain
        pixels = self.world.render(levels, frame.exposure_us, gain, self._lamp_time_s(frame.timestamp_ns))
        if pixels.shape != frame.pixels.shape:
            raise CameraError(
                f"aravis-fake: the scene renders {pixels.shape} but the fake delivers "
                f"{frame.pixels.shape}; expected the ROI to be the scene's size"
            )
        with self._pending_lock:
            self._rendered_levels.append(levels)
        return dataclasses.replace(frame, pixels=pixels)

    def _lamp_time_s(self, timestamp_ns: int) -> float | None:
        """A frame's exposure start on a flickering lamp's clock: its timestamp on the camera's clock, from the
        first frame's (the mains keeps real time, and so does the fake's clock: the lamp is where the recorded
        timestamps say, as with a real camera). None under a steady ambient or without a timestamp."""
        if getattr(self.world, "ambient_modulation", None) is None or timestamp_ns <= 0:
            return None
        if self._first_timestamp_ns is None:
            self._first_timestamp_ns = timestamp_ns
        return (timestamp_ns - self._first_timestamp_ns) * 1e-9

    def _take_levels(self) -> tuple[float, ...] | None:
        with self._pending_lock:
            return self._pending.popleft() if self._pending else None

    def stop(self) -> None:
        """Stop acquisition and the trigger-line thread (a trigger not yet taken is forgotten at the next start)."""
        if self._pulse_thread is not None:
            self._pulses.put(None)
            self._pulse_thread.join(timeout=5.0)
            self._pulse_thread = None
        self.aravis.stop()

    def close(self) -> None:
        """Release the fake camera."""
        self.aravis.close()
