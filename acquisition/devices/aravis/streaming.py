"""An Aravis camera's stream: the buffer pool, the popping thread, triggers and frames."""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import replace

from msflash.acquisition.devices.aravis.buffers import (
    CONTROL_LOST,
    ZERO_COPY_PROTOCOLS,
    Bad,
    BufferPool,
    Failure,
    Good,
    PoppedBuffer,
    SpareStream,
)
from msflash.acquisition.devices.aravis.camera_records import (
    AcquisitionStats,
    FrameTiming,
)
from msflash.acquisition.devices.aravis.gi_typelib import Aravis, GLib
from msflash.acquisition.devices.aravis.gv_stream import create_gv_stream
from msflash.acquisition.devices.aravis.pixel_layouts import (
    GV_FRAME_ID_WRAP,
    decode_pixels,
    frame_id_gap,
    is_zero_copy_format,
    view_pixels,
)
from msflash.acquisition.devices.aravis.sync_lines import SyncLines
from msflash.acquisition.devices.camera import NativeGain, RawFrame
from msflash.acquisition.errors import (
    CameraDisconnectedError,
    CameraError,
    FrameLostError,
    FrameTimeoutError,
)
from msflash.acquisition.plan import CapturePlan

log = logging.getLogger(__name__)

_POP_POLL_US = 10_000
"""How long the pump thread waits in one ``timeout_pop_buffer`` call, so stop() is prompt (a frame
ends the wait at once; only stop() waits for the timeout)."""
_MAX_POOL_BYTES = 512 * 1024 * 1024
"""Upper bound on the buffer pool; a plan asking for more buffers gets fewer, with a warning."""


class Streaming(SyncLines):
    """Acquisition: each step's exposure and gain, the stream and its buffers (one dedicated popping
    thread, every status checked, frame-id gaps found), software triggers and :meth:`next_frame`."""

    @property
    def stats(self) -> AcquisitionStats:
        """Frame accounting of the current (or last) acquisition."""
        with self._stats_lock:
            return replace(self._stats, statuses=dict(self._stats.statuses))

    def _apply_step(self, index: int, plan: CapturePlan) -> tuple[float, float, NativeGain | None]:
        # Write only what changes: each write and read-back is a GVCP round trip on the trigger path.
        step = plan.steps[index]
        requested = self._step_request
        exposure, gain, native = self._current
        if requested is None or requested[0] != step.exposure_us:
            exposure = self.set_exposure_us(step.exposure_us)
        if requested is None or requested[1] != step.gain:
            gain = self.set_gain(step.gain)
            native = self._native_gain
        self._step_request = (step.exposure_us, step.gain)
        log.debug("%s: step %d exposure %.1f us gain %.3f", self._name, index, exposure, gain)
        self._current = (exposure, gain, native)
        return exposure, gain, native

    def _build_stream(self, n_buffers: int) -> None:
        # Creating (and destroying) a stream costs tens of ms on GigE Vision (socket, thread, stream
        # channel registers): the stream of the previous capture is reused, with its buffers, when
        # the frame layout, the payload and the pool still fit. Buffers it still holds are stale:
        # start() drains them.
        spare, self._spare = self._spare, None
        fits = False
        try:
            try:
                payload = int(self._camera.get_payload())
            except GLib.Error as err:
                raise self._fail("reading", "PayloadSize", err) from err
            layout = (str(self.get_feature("PixelFormat")),) + self.roi[2:]
            fits = (
                spare is not None
                and (spare.pool.payload, spare.layout) == (payload, layout)
                and (spare.n_buffers >= n_buffers)
            )
        finally:
            if spare is not None and not fits:
                spare.pool.release()
        if spare is not None and fits:
            self._pool, self._n_buffers, self._layout_key = spare.pool, spare.n_buffers, layout
            self._stale_before_ns = 1  # start() sets the acquisition's start time
            return
        try:
            if self._protocol == "gige":
                stream = create_gv_stream(self._camera, payload)  # the UDP socket, sized for frames
            else:
                stream = self._camera.create_stream(None, None)
        except GLib.Error as err:
            raise self._fail("creating the stream for", "PayloadSize", err) from err
        if stream is None:
            raise CameraError(f"{self._name}: no stream channel; expected the camera to stream images")
        if n_buffers * payload > _MAX_POOL_BYTES:
            reduced = max(2, _MAX_POOL_BYTES // payload)
            log.warning(
                "%s: %d buffers of %d bytes exceed %d MiB; using %d",
                self._name,
                n_buffers,
                payload,
                _MAX_POOL_BYTES >> 20,
                reduced,
            )
            n_buffers = reduced
        zero_copy = self._zero_copy and self._protocol in ZERO_COPY_PROTOCOLS and is_zero_copy_format(layout[0])
        pool = BufferPool(stream, payload, zero_copy)
        try:
            pool.fill(n_buffers)
        except BaseException:
            pool.release()
            raise
        self._pool = pool
        self._n_buffers = n_buffers
        self._layout_key = layout
        self._stale_before_ns = 0

    @property
    def pool_arrays(self) -> tuple[int, int]:
        """Arrays the camera holds for zero-copy frames: (behind buffers in the stream, spares).

        The first stays at the pool size and the second only shrinks during an acquisition
        (:meth:`prepare` tops it up): frames handed out are the caller's, not the camera's.
        Both are 0 for a copying camera and after :meth:`close`.
        """
        pool = self._pool if self._pool is not None else (self._spare.pool if self._spare is not None else None)
        return pool.counts if pool is not None else (0, 0)

    def start(self) -> None:
        """Start acquisition and the thread that pops buffers."""
        if self._acquiring:
            return
        pool = self._pool
        if pool is None:
            raise CameraError(f"{self._name}: start() before prepare(); expected a prepared camera")
        self._queue = queue.Queue()
        self._triggered_settings.clear()
        self._n_triggered = self._n_consumed = 0
        self._last_frame_id = None
        with self._stats_lock:
            self._stats = AcquisitionStats(n_buffers=self._n_buffers)
        self._pump_stop.clear()
        if self._stale_before_ns:  # a reused stream: drop what the previous acquisition left in it
            while (buffer := pool.stream.try_pop_buffer()) is not None:
                pool.stream.push_buffer(buffer)
            self._stale_before_ns = time.time_ns()
        self._pump = threading.Thread(
            target=self._pump_buffers, args=(pool,), name=f"aravis-pump-{self._serial}", daemon=True
        )
        self._pump.start()
        try:
            self._camera.start_acquisition()
        except GLib.Error as err:
            self._stop_pump()
            raise self._fail("starting", "AcquisitionStart", err) from err
        self._acquiring = True

    def _pump_buffers(self, pool: BufferPool) -> None:
        # A dedicated thread popping with a timeout: stream callbacks lost most frames under load.
        stale_before_ns = self._stale_before_ns
        while not self._pump_stop.is_set():
            item: Good | Bad | Failure | None = None
            with pool.fetch(_POP_POLL_US) as popped:  # pushed back at the end of the block unless handed out
                if popped is None:
                    continue
                try:
                    item = None if self._not_a_frame(popped, stale_before_ns) else self._take(popped)
                except Exception as exc:  # noqa: BLE001 - handed to the consumer, never lost
                    item = Failure(exc)
            if item is None:
                continue
            # The caller's thread, woken by the queue, need not wait for this one: a copy is already
            # made, and a handed-out buffer's replacement is pushed only now.
            self._queue.put(item)
            if popped.handed_out:
                try:
                    pool.replace()
                except Exception as exc:  # noqa: BLE001 - the pool is one buffer short, frames still flow
                    log.warning(
                        "%s: no buffer to replace one handed out (%s); the pool shrinks by one", self._name, exc
                    )

    def _not_a_frame(self, popped: PoppedBuffer, stale_before_ns: int) -> bool:
        """A buffer of the previous acquisition, or one Aravis never filled (counted): no frame."""
        buffer = popped.buffer
        if 0 < int(buffer.get_system_timestamp()) < stale_before_ns:
            return True  # a frame of the previous acquisition still in flight when it stopped
        if buffer.get_status() == Aravis.BufferStatus.CLEARED:
            # Never filled: Aravis hands a buffer back untouched when the packet that took it could
            # not start a frame (a stray datagram; gv_stream.py). Not a frame.
            with self._stats_lock:
                self._stats = replace(self._stats, buffers_unfilled=self._stats.buffers_unfilled + 1)
            return True
        return False

    def _take(self, popped: PoppedBuffer) -> Good | Bad | Failure:
        """What the consumer gets for one popped buffer: a view of its own array (handed out with it,
        never pushed again), else a copy of its pixels."""
        buffer = popped.buffer
        pixel_format, width, height = self._layout_key
        status = buffer.get_status()
        frame_id = int(buffer.get_frame_id())
        if status != Aravis.BufferStatus.SUCCESS:
            return Bad(frame_id, status.value_nick)
        w, h = buffer.get_image_width(), buffer.get_image_height()
        if (w, h) != (width, height):
            return Failure(CameraError(f"{self._name}: frame {frame_id} is {w}x{h}; expected {width}x{height}"))
        received = int(buffer.get_system_timestamp())
        timestamp = int(buffer.get_timestamp()) or received
        array = popped.array()
        if array is None:
            pixels = decode_pixels(buffer.get_data(), pixel_format, w, h, where=self._name)
            return Good(pixels, frame_id, timestamp, received, popped.popped_ns)
        pixels = view_pixels(array, pixel_format, w, h, where=self._name)
        popped.hand_out()  # last: nothing after it can fail and push the buffer back
        return Good(pixels, frame_id, timestamp, received, popped.popped_ns)

    def _step_label(self, index: int) -> str:
        plan = self._plan
        if plan is not None and index < len(plan.steps):
            step = plan.steps[index]
            # A sequence's steps are named by their index (a retake's plan holds the steps left,
            # from the lost one); a plan repeating one step (the bench, live view) counts frames.
            distinct = len({s.index for s in plan.steps}) == len(plan.steps)
            return f"step {step.index if distinct else index} '{step.label}'"
        return f"frame {index} (beyond the plan)"

    def trigger(self) -> None:
        """Apply the next step's exposure and gain, then issue a software trigger (no-op otherwise)."""
        if self._trigger.mode != "software":
            return
        if not self._acquiring:
            raise CameraError(f"{self._name}: trigger() before start(); expected a started acquisition")
        index = self._n_triggered
        settings = self._current
        if self._plan is not None and index < len(self._plan.steps):
            try:
                settings = self._apply_step(index, self._plan)
            except CameraError as err:
                raise type(err)(f"{err} (while setting up {self._step_label(index)})") from err
        try:
            self._live().execute_command("TriggerSoftware")
        except GLib.Error as err:
            raise self._fail(f"triggering {self._step_label(index)}:", "TriggerSoftware", err) from err
        self._triggered_settings.append(settings)
        self._n_triggered += 1

    def next_frame(self, timeout_s: float) -> RawFrame:
        """The next complete frame.

        Raises
        ------
        FrameTimeoutError
            Nothing arrived within ``timeout_s``; names the step.
        FrameLostError
            The frame arrived incomplete or frame ids were skipped; names the step and frame id.
            Incomplete frames are counted in :attr:`stats` and never returned.
        CameraDisconnectedError
            Aravis reported ``control-lost``, or nothing arrived within ``timeout_s`` and the camera
            no longer answers a register read (:meth:`_silence`): a camera switched off or
            unplugged, told apart from a trigger problem before its heartbeat fails.
        """
        if not self._acquiring:
            raise CameraError(f"{self._name}: next_frame() before start(); expected a started acquisition")
        index = self._n_consumed
        where = self._step_label(index)
        if self._control_lost.is_set():
            raise CameraDisconnectedError(
                f"{self._name}: control lost before {where}; expected a "
                "connected camera — check power and cable, then reopen it"
            )
        try:
            item = self._queue.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            stats = self.stats
            silent = self._silence()
            if silent is not None:
                raise CameraDisconnectedError(
                    f"{self._name}: no frame for {where} within {timeout_s:.3g} s, and the camera no longer "
                    f"answers ({silent}); expected a connected camera — check its power and cable, then "
                    f"reopen it ({stats.frames_good} good frame(s) before)"
                ) from None
            raise FrameTimeoutError(
                f"{self._name}: no frame for {where} within {timeout_s:.3g} s; expected one frame per "
                f"{'trigger' if self._trigger.mode != 'free' else 'frame period'} "
                f"({stats.frames_good} good, {stats.frames_incomplete} incomplete so far) — check the "
                "trigger source and wiring"
            ) from None
        if item is CONTROL_LOST:
            raise CameraDisconnectedError(
                f"{self._name}: control lost while waiting for {where}; expected a "
                "connected camera — check power and cable, then reopen it"
            )
        settings = self._triggered_settings.popleft() if self._triggered_settings else self._current
        self._n_consumed += 1
        if isinstance(item, Failure):
            raise CameraError(f"{self._name}: {where}: {item.error}") from item.error
        self._refuse_lost(item, where)
        with self._stats_lock:
            self._stats = replace(self._stats, frames_good=self._stats.frames_good + 1)
        if self._trigger.mode != "software" and self._plan is not None and self._n_consumed < len(self._plan.steps):
            # Without software triggers the next exposure is set between frames: the plan's
            # deadtime must cover these writes.
            self._apply_step(self._n_consumed, self._plan)
        exposure_us, gain, native = settings
        frame = RawFrame(item.pixels, item.frame_id, item.timestamp_ns, exposure_us, gain, native)
        self._last_timing = FrameTiming(item.timestamp_ns, item.received_ns, item.popped_ns, time.time_ns())
        return frame

    def _refuse_lost(self, item: Good | Bad, where: str) -> None:
        """Raise :class:`FrameLostError` for an incomplete frame (counted) or a gap in the frame ids."""
        if isinstance(item, Bad) and item.frame_id == 0 and self._protocol == "gige":
            # Aravis names no block id (0, never sent on GigE Vision) for a frame it could not
            # identify: it is taken as the next frame, so neither it nor the frame after it counts
            # the whole 16-bit range as missing.
            missing = 0
            previous = self._last_frame_id
            if previous is not None:  # 65535 is followed by 1 (16-bit block ids), beyond by +1 (64-bit)
                self._last_frame_id = 1 if previous == GV_FRAME_ID_WRAP - 1 else previous + 1
        else:
            missing = self._check_continuity(item.frame_id)
        if isinstance(item, Bad):
            with self._stats_lock:
                statuses = dict(self._stats.statuses)
                statuses[item.status] = statuses.get(item.status, 0) + 1
                self._stats = replace(
                    self._stats, frames_incomplete=self._stats.frames_incomplete + 1, statuses=statuses
                )
            raise FrameLostError(
                f"{self._name}: frame {item.frame_id} for {where} arrived incomplete "
                f"(buffer status {item.status}); expected a complete frame — check the "
                "link (packet size, MTU, cable, bandwidth)"
            )
        if missing:
            raise FrameLostError(
                f"{self._name}: {missing} frame(s) lost before frame {item.frame_id} "
                f"({where}); expected consecutive frame ids — enlarge the buffer pool "
                "or lower the frame rate"
            )

    def _silence(self) -> str | None:
        """Why the camera no longer answers, or None when it does (asked after a frame timeout).

        A GigE Vision camera that is switched off or unplugged raises ``control-lost`` only when its
        heartbeat fails, seconds later: a frame timeout then read as a trigger problem. One read of
        a bootstrap register (GigE Vision ``Version``, 0x0000, which every device has) tells them
        apart: an answer in milliseconds, or a timeout after Aravis's retries (about 4 s) — after
        which the control writes of stopping are skipped (each would wait its retries again).
        Other transports report a lost device themselves.
        """
        if self._control_lost.is_set():
            return "control lost"
        if self._protocol != "gige" or self._device is None:
            return None
        try:
            self._device.read_register(0x0000)
        except GLib.Error as err:
            self._unreachable = True
            return "control lost" if self._control_lost.is_set() else err.message
        return None

    @property
    def last_frame_timing(self) -> FrameTiming | None:
        """Stage times of the frame :meth:`next_frame` returned last (None before the first)."""
        return self._last_timing

    def _check_continuity(self, frame_id: int) -> int:
        previous, self._last_frame_id = self._last_frame_id, frame_id
        if previous is None:
            return 0
        wrap = GV_FRAME_ID_WRAP if self._protocol == "gige" and max(previous, frame_id) < GV_FRAME_ID_WRAP else None
        gap = frame_id_gap(previous, frame_id, wrap=wrap, skip_zero=self._protocol == "gige")
        if gap > 0:
            with self._stats_lock:
                self._stats = replace(self._stats, frames_missing=self._stats.frames_missing + gap)
            return gap
        return 0

    def _stop_pump(self) -> bool:
        """Stop the popping thread; False when it did not exit (it may still touch the stream)."""
        self._pump_stop.set()
        if self._pump is not None:
            self._pump.join(timeout=5.0)
            if self._pump.is_alive():  # pragma: no cover - Aravis stuck in pop
                log.error("%s: buffer thread did not stop", self._name)
                return False
        self._pump = None
        return True

    def stop(self) -> None:
        """Stop acquisition, stop the buffer thread and drop the stream; idempotent.

        The order keeps Aravis from writing into freed memory: acquisition stops first, then the
        popping thread, then the stream is kept for the next :meth:`prepare` with its buffers and
        their arrays, or — control lost — released (its thread stopped, its buffers deleted)
        before the arrays go (see :class:`BufferPool`).
        """
        if self._acquiring and self._camera is not None:
            try:
                if not (self._control_lost.is_set() or self._unreachable):
                    self._camera.stop_acquisition()
            except GLib.Error as err:
                log.warning("%s: AcquisitionStop failed: %s", self._name, err.message)
        self._acquiring = False
        stopped = self._stop_pump()
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if not stopped:  # pragma: no cover - the thread may still push a buffer back
            pool.abandon()
        elif self._control_lost.is_set() or self._unreachable:
            # Aravis waits out its retries here and again at close (how long: docs/measurements.md).
            log.warning(
                "%s: releasing a camera that no longer answers; Aravis waits out its control "
                "retries first (about 10 s)",
                self._name,
            )
            pool.release()
        elif self._stats.frames_incomplete or self._stats.frames_missing:
            # A stream that lost frames is not reused: Aravis may still hold a partial frame of
            # it, which the next acquisition would receive in place of its first frame.
            pool.release()
        else:
            self._spare = SpareStream(pool, self._n_buffers, self._layout_key)
