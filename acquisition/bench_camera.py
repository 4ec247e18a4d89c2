"""Camera bench: AravisCamera against a bare Aravis loop on the same GigE Vision fake, one run.

Figures (returned by :func:`camera_bench`, printed by ``msflash bench``):

- ``fps_ratio``: frames per second AravisCamera delivers (owned numpy copies, status and
  frame-id checks, one popping thread) at 1280×1024 Mono16 with the fake free-running, divided by
  the frames per second of a bare pop/check/push loop on the same fake. Target ≥ 0.95; each
  side's drops are reported and a run with drops says so.
- ``latency_excess_ms``: mean software-trigger-to-frame latency of AravisCamera minus the bare
  loop's. Target ≤ 1 ms. The GigE Vision fake starts frames on a coarse internal tick (about
  5 ms, measured), so a latency is the transfer time plus a wait quantised by that tick; each
  trigger is therefore sent after a random delay of up to one tick (both sides alike) and the
  means are compared, which turns the quantisation into noise that averages out instead of a
  bias that depends on phase.
"""

from __future__ import annotations

import logging
import math
import random
import statistics
import time
from typing import Any

from acquisition.errors import FrameLostError
from acquisition.plan import CapturePlan, CaptureStep

log = logging.getLogger(__name__)

_FAKE_TICK_S = 0.005
"""Trigger-to-frame latency on the fake comes in steps of about this (measured on 0.8.26)."""

FPS_RATIO_TARGET = 0.95
LATENCY_EXCESS_TARGET_MS = 1.0


def _plan(n: int, exposure_us: float, trigger: str) -> CapturePlan:
    step = CaptureStep(0, "ambient", (0.0,), exposure_us)
    return CapturePlan(tuple(step for _ in range(n)), trigger=trigger)  # type: ignore[arg-type]


def camera_bench(n_frames: int = 150, n_triggers: int = 80, repeats: int = 3, width: int = 1280, height: int = 1024,
                 pixel_format: str = "Mono16", frame_rate_hz: float = 1000.0,
                 exposure_us: float = 100.0) -> dict[str, Any]:
    """Measure AravisCamera against a bare Aravis loop on the in-process GigE Vision fake.

    Parameters
    ----------
    n_frames
        Frames per throughput run (the fake free-runs as fast as ``frame_rate_hz`` allows).
    n_triggers
        Software triggers per latency run.
    repeats
        Interleaved throughput runs of each side; the best of each is kept.
    width, height, pixel_format
        Image format of every run.
    frame_rate_hz
        AcquisitionFrameRate asked of the fake in the throughput runs.
    exposure_us
        Exposure of every frame.

    Returns
    -------
    dict
        ``fps_msflash``, ``fps_bare``, ``fps_ratio``, drops of each, ``latency_ms_msflash``,
        ``latency_ms_bare`` (means), ``latency_excess_ms``, the targets and whether they are met.
    """
    from acquisition.aravis_camera import (
        AravisCamera,
        AravisGvFake,
        StrobeConfig,
        TriggerConfig,
        bare_aravis_run,
    )

    roi = (0, 0, width, height)
    free_run = TriggerConfig(mode="free", frame_rate_hz=frame_rate_hz)

    def msflash_throughput(address: str) -> tuple[float, int]:
        with AravisCamera(address, interfaces="gige", pixel_format=pixel_format, roi=roi,
                          strobe=StrobeConfig(line="Line1")) as camera:
            plan = _plan(n_frames, exposure_us, "camera")
            camera.prepare(plan)
            camera.configure_trigger(free_run)
            camera.start()
            first = last = time.perf_counter()
            for i in range(n_frames):
                try:
                    camera.next_frame(plan.frame_timeout_s)
                except FrameLostError:
                    pass  # counted in stats
                last = time.perf_counter()
                if i == 0:
                    first = last
            camera.stop()
            stats = camera.stats
        fps = (n_frames - 1) / (last - first) if last > first else float("nan")
        return fps, stats.frames_incomplete + stats.frames_missing

    with AravisGvFake(serial="MSFBENCH", trigger_frequency_hz=1000.0) as fake:
        # Throughput, free-running, interleaved bare/msflash ``repeats`` times (best of each) so that warm-up
        # and drift on a shared machine do not favour either side.
        fps_bare, fps_msflash, drops_bare, drops_msflash = 0.0, 0.0, 0, 0
        for _ in range(repeats):
            bare = bare_aravis_run(fake.address, width=width, height=height, pixel_format=pixel_format,
                                   n_frames=n_frames, software_trigger=False, frame_rate_hz=frame_rate_hz)
            fps_bare = max(fps_bare, (bare.frames + bare.bad - 1) / bare.seconds)
            drops_bare += bare.bad + bare.missing
            fps, drops = msflash_throughput(fake.address)
            fps_msflash = max(fps_msflash, fps)
            drops_msflash += drops

        # Latency, software trigger to frame in hand, in alternating blocks for the same reason.
        bare_latencies: list[float] = []
        latencies: list[float] = []
        block = max(1, n_triggers // 4)
        for _ in range(4):
            bare_latencies += bare_aravis_run(fake.address, width=width, height=height, pixel_format=pixel_format,
                                              n_frames=block, software_trigger=True,
                                              dither_s=_FAKE_TICK_S).latencies_s
            with AravisCamera(fake.address, interfaces="gige", pixel_format=pixel_format, roi=roi) as camera:
                plan = _plan(block, exposure_us, "software")
                camera.prepare(plan)
                camera.start()
                for _ in range(block):
                    time.sleep(random.uniform(0.0, _FAKE_TICK_S))
                    sent = time.perf_counter()
                    camera.trigger()
                    camera.next_frame(plan.frame_timeout_s)
                    latencies.append(time.perf_counter() - sent)
                camera.stop()
    latency_msflash = statistics.fmean(latencies) * 1e3
    latency_bare = statistics.fmean(bare_latencies) * 1e3
    ratio = fps_msflash / fps_bare if fps_bare > 0 else math.nan
    report = {
        "format": f"{width}x{height} {pixel_format}",
        "fps_msflash": fps_msflash,
        "fps_bare": fps_bare,
        "fps_ratio": ratio,
        "fps_ratio_target": FPS_RATIO_TARGET,
        "drops_msflash": drops_msflash,
        "drops_bare": drops_bare,
        "latency_ms_msflash": latency_msflash,
        "latency_ms_bare": latency_bare,
        "latency_excess_ms": latency_msflash - latency_bare,
        "latency_excess_target_ms": LATENCY_EXCESS_TARGET_MS,
        "latency_triggers": len(latencies),
    }
    report["fps_target_met"] = bool(ratio >= FPS_RATIO_TARGET and report["drops_msflash"] == 0)
    report["latency_target_met"] = bool(report["latency_excess_ms"] <= LATENCY_EXCESS_TARGET_MS)
    return report
