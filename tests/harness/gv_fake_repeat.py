"""Repeat a short capture on the GigE Vision fake and count repetitions that lost a frame.

Run as ``python -m tests.harness.gv_fake_repeat N [PIXEL_FORMAT] [small]`` (repository root on
``PYTHONPATH``): N times, the fake at 127.0.0.1 and an ``AravisCamera`` on it, prepared for four
software-triggered frames (200x186, or 64x48 with ``small``). Prints one line: repetitions with a
lost frame, unfilled buffers skipped, and the errors. ``docs/steady-tests.md`` runs it under load
beside :mod:`tests.harness.loopback_noise`.
"""

from __future__ import annotations

import collections
import sys


def repeat(n: int, pixel_format: str = "Mono16", small: bool = False) -> str:
    """The summary line for ``n`` repetitions."""
    from msflash.acquisition.devices.aravis.camera import AravisCamera
    from msflash.acquisition.devices.aravis.fake_log import mute_unfilled_format_warning
    from msflash.acquisition.devices.aravis.gv_fake import AravisGvFake
    from msflash.acquisition.errors import CameraError
    from msflash.acquisition.plan import CapturePlan, CaptureStep

    roi = (0, 0, 64, 48) if small else (0, 0, 200, 186)
    unmute = mute_unfilled_format_warning()
    why: collections.Counter[str] = collections.Counter()
    failed = unfilled = 0
    try:
        for _ in range(n):
            steps = tuple(CaptureStep(i, "ambient" if i == 0 else "led", (0.0,), 8000.0) for i in range(4))
            plan = CapturePlan(steps, trigger="software")
            lost = False
            with (
                AravisGvFake(serial="REPEAT") as fake,
                AravisCamera(fake.address, interfaces="gige", pixel_format=pixel_format, roi=roi) as camera,
            ):
                camera.prepare(plan)
                camera.start()
                for _step in plan.steps:
                    camera.trigger()
                    try:
                        camera.next_frame(plan.frame_timeout_s)
                    except CameraError as err:
                        lost = True
                        why[str(err).split("; expected")[0].split("arrived")[-1][:60]] += 1
                unfilled += getattr(camera.stats, "buffers_unfilled", 0)
                camera.stop()
            failed += lost
    finally:
        unmute()
    return f"{failed}/{n} repetitions lost a frame; unfilled buffers skipped {unfilled}; {dict(why)}"


if __name__ == "__main__":
    args = sys.argv[1:]
    print(repeat(int(args[0]), args[1] if len(args) > 1 and args[1] != "small" else "Mono16", "small" in args))
