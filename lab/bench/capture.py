"""Capture bench: the whole capture → estimate → flash → re-capture loop on the GigE Vision fake.

The ``aravis-fake`` rig (AravisCamera on the fake at 127.0.0.1, booth emulator on a pty, the real
``LedBooth`` driver; in its test-pattern form, ``rendered=False``, so the figures are the transport's
without the scene renderer's cost) runs booth master: the booth pulses the trigger once per period, so the
camera runs at a fixed frame rate (``frame_rate_hz``; the exposure is what fills the rest of the
period, :func:`acquisition.session.booth_guard.booth_period_us`). Each run is one stream of ambient + k LEDs
+ flash (:func:`acquisition.session.capture.run_capture_with_flash`): the table is armed with the flash
step held; when the last LED frame arrives the ambient is estimated from the frames in memory
(:class:`acquisition.session.flash_session.FlashSession`, prepared once per rig), the complementary flash
solved, its exposure predicted, and one ``PSET`` releases the held step — what ``msflash run``
does. Frames are written by a writer thread (:mod:`acquisition.sequence.async_writer`).

Figures (one run of the bench, :func:`capture_bench`):

- ``wall_ratio``: wall time from the start of the LED sequence to the flash frame's arrival,
  divided by (k + 2) frame periods — the ideal of a camera streaming k + 2 frames back to back.
  Target ≤ 1.15 (median over runs; each run's ratio is listed).
- ``latency_ms``: from the last LED frame's arrival (``next_frame`` returns it) to the booth's
  flash trigger pulse: handing that frame to the writer, estimation, flash solving, exposure, the
  ``PSET`` round trip and the booth's LED settle time. Median and
  max over the runs. Targets: median ≤ 5 ms, max below one frame period at 60 fps (16.7 ms).
- ``host_latency_ms``: the compute + serial part alone — from the same arrival to the booth
  setting the flash step's LEDs on reading the ``PSET`` line (the emulator's release of the held
  step). ``latency_ms`` is this plus the booth's modelled LED settle time (``settle_s``, 1 ms
  here) and its timer's wake-up. Reported beside it; the target is judged on ``latency_ms``.
- its parts (``latency_parts_ms`` per run, ``latency_parts_ms_median``; ms): ``handoff_ms`` from the arrival to the start of the decision (pairing
  with the booth's ``TRIG``, queueing to the writer, the session's block sums of the last frame);
  ``compute_ms`` the estimation + solving (:meth:`FlashSession.decide`); ``exposure_ms`` the flash
  exposure prediction (:meth:`FlashSession.flash_exposure`, from the rates taken as frames arrived);
  ``replan_ms`` from the end of the decision to sending the ``PSET`` (the camera takes the flash
  step); ``pset_to_trigger_ms`` from the ``PSET`` being sent to the pulse, which includes the
  booth's LED settle time (``settle_s``, 1 ms here) — the booth's part, not the host's. These five
  add up to each run's latency. ``pset_to_release_ms`` is the serial part of the last: from
  sending the ``PSET`` to the booth setting the step's LEDs. ``pset_ms``, the ``PSET`` round trip (sent to reply), overlaps the
  settle time: the booth starts the step when it reads the line, not when the host reads the reply.

The fake's frames are test patterns, so the estimate means nothing here (it may be degenerate);
only time is measured.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from msflash.acquisition.plan import CapturePlan, PlanTiming
from msflash.acquisition.session.booth_guard import READOUT_US, TRIGGER_PULSE_US
from msflash.led_controller.booth import LedBooth

WALL_RATIO_TARGET = 1.15
LATENCY_MEDIAN_TARGET_MS = 5.0


def capture_bench(
    runs: int = 11, frame_rate_hz: float = 60.0, width: int = 320, height: int = 240, pixel_format: str = "Mono16"
) -> dict[str, Any]:
    """Time the capture loop on the GigE Vision fake; see the module notes for the figures.

    Parameters
    ----------
    runs
        Sequences timed (each: ambient + 7 LEDs + flash); the medians are over these.
    frame_rate_hz
        The booth's trigger rate; the exposure fills the period.
    width, height, pixel_format
        Frame format of the fake.
    """
    from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
    from msflash.acquisition.session.capture import run_capture_with_flash
    from msflash.acquisition.session.exposure import ExposurePolicy
    from msflash.acquisition.session.flash_session import FlashSession
    from msflash.acquisition.session.rig import open_aravis_fake_rig

    period_us = 1e6 / frame_rate_hz
    settle_s, deadtime_s = 0.001, 0.001
    exposure_us = period_us - settle_s * 1e6 - TRIGGER_PULSE_US - deadtime_s * 1e6 - READOUT_US
    if exposure_us <= 0:
        raise ValueError(f"capture bench: {frame_rate_hz} fps leaves no time for an exposure; expected ≤ 200 fps")
    timing: PlanTiming = {"settle_s": settle_s, "deadtime_s": deadtime_s, "trigger": "booth"}
    ratios: list[float] = []
    latencies: list[float] = []
    host_latencies: list[float] = []
    computes: list[float] = []
    with (
        tempfile.TemporaryDirectory(prefix="msflash-bench-capture-") as scratch,
        open_aravis_fake_rig(width=width, height=height, pixel_format=pixel_format, rendered=False) as rig,
    ):
        n_leds = rig.led_spectra.count
        camera, emulator = rig.camera, rig.emulator
        assert emulator is not None
        arrivals: list[float] = []
        pulses: list[float] = []
        psets: list[tuple[float, float]] = []
        booth = rig.booth
        assert isinstance(booth, LedBooth)  # the sim rig's: a sequenced booth
        real_next, real_pulse, real_set_step = camera.next_frame, emulator.on_trigger_out, booth.set_step
        real_release = emulator._release_hold  # the booth's side of PSET: the held step's LEDs are set
        releases: list[float] = []

        def timed_next(timeout_s: float):
            frame = real_next(timeout_s)
            arrivals.append(time.perf_counter())
            return frame

        def timed_pulse(*args: Any) -> None:
            pulses.append(time.perf_counter())
            if real_pulse is not None:
                real_pulse(*args)

        def timed_set_step(*args: Any, **kwargs: Any) -> None:
            sent = time.perf_counter()
            real_set_step(*args, **kwargs)
            psets.append((sent, time.perf_counter()))

        def timed_release() -> None:
            releases.append(time.perf_counter())
            real_release()

        camera.next_frame = timed_next
        emulator._release_hold = timed_release  # type: ignore[method-assign]
        emulator.on_trigger_out = timed_pulse
        booth.set_step = timed_set_step  # type: ignore[method-assign]
        policy = ExposurePolicy()
        session: FlashSession | None = None
        parts: dict[str, list[float]] = {
            name: []
            for name in (
                "handoff_ms",
                "compute_ms",
                "exposure_ms",
                "replan_ms",
                "pset_to_trigger_ms",
                "pset_to_release_ms",
                "pset_ms",
            )
        }
        for run in range(runs + 1):  # run 0 warms up (imports, first stream) and is not counted
            arrivals.clear()
            pulses.clear()
            psets.clear()
            releases.clear()
            writer = rig.sequence_writer(Path(scratch) / f"run{run}")
            if session is None:  # once per rig: LED/camera model, target response
                session = FlashSession.prepare(
                    writer.sequence, exposure_limits_us=(1.0, exposure_us), exposure_policy=policy
                )
            session.begin()
            plan = CapturePlan.ambient_then_each_led(n_leds, exposure_us, **timing)
            decision = _TimedDecision(session, arrivals, pulses)
            mark = decision.mark

            started = time.perf_counter()
            with AsyncSequenceWriter(writer) as background:
                run_capture_with_flash(camera, rig.booth, plan, background, decision, handlers=(session,))
                finished = arrivals[-1]
            if run == 0:
                continue
            ratios.append((finished - started) / ((n_leds + 2) * period_us * 1e-6))
            pulse = pulses[int(mark["pulses"])]
            latencies.append((pulse - mark["last_arrival"]) * 1e3)
            host_latencies.append((releases[-1] - mark["last_arrival"]) * 1e3)
            computes.append(mark["compute"] * 1e3)
            sent, replied = psets[-1]
            for name, value in (
                ("handoff_ms", mark["began"] - mark["last_arrival"]),
                ("compute_ms", mark["compute"]),
                ("exposure_ms", mark["exposure"]),
                ("replan_ms", sent - mark["decided"]),
                ("pset_to_trigger_ms", pulse - sent),
                ("pset_to_release_ms", releases[-1] - sent),
                ("pset_ms", replied - sent),
            ):
                parts[name].append(value * 1e3)
    period_ms = period_us * 1e-3
    report: dict[str, Any] = {
        "format": f"{width}x{height} {pixel_format}, booth master at {frame_rate_hz:g} fps, {n_leds} LEDs",
        "exposure_us": exposure_us,
        "runs": runs,
        "wall_ratio": statistics.median(ratios),
        "wall_ratios": ratios,
        "wall_ratio_target": WALL_RATIO_TARGET,
        "latency_ms_median": statistics.median(latencies),
        "latency_ms_max": max(latencies),
        "latencies_ms": latencies,
        "host_latency_ms_median": statistics.median(host_latencies),
        "host_latency_ms_max": max(host_latencies),
        "host_latencies_ms": host_latencies,
        "compute_ms_median": statistics.median(computes),
        "latency_parts_ms_median": {name: statistics.median(values) for name, values in parts.items()},
        "latency_parts_ms": parts,
        "booth_settle_ms": settle_s * 1e3,
        "latency_median_target_ms": LATENCY_MEDIAN_TARGET_MS,
        "frame_period_ms": period_ms,
    }
    report["wall_target_met"] = bool(report["wall_ratio"] <= WALL_RATIO_TARGET)
    report["latency_target_met"] = bool(
        report["latency_ms_median"] <= LATENCY_MEDIAN_TARGET_MS and report["latency_ms_max"] < 1e3 / 60.0
    )
    return report


__all__ = ["capture_bench"]


class _TimedDecision:
    """The bench's flash decision (a :class:`~acquisition.session.engine.FlashDecider`): the flash session's,
    with the hand-off, compute and exposure-prediction times marked."""

    def __init__(self, session: Any, arrivals: list[float], pulses: list[float]) -> None:
        self.session, self.arrivals, self.pulses = session, arrivals, pulses
        self.mark: dict[str, float] = {}

    def decide_flash(self) -> Any:
        import warnings

        from msflash.acquisition.session.engine import FlashChoice

        mark = self.mark
        began = time.perf_counter()
        mark["last_arrival"] = self.arrivals[-1]
        mark["pulses"] = len(self.pulses)
        mark["began"] = began
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            levels = self.session.decide("complementary", sanitise=True).levels
        solved = time.perf_counter()
        flash_us = self.session.flash_exposure(levels)
        mark["compute"] = solved - began
        mark["decided"] = time.perf_counter()
        mark["exposure"] = mark["decided"] - solved
        return FlashChoice(tuple(float(v) for v in levels), float(flash_us))
