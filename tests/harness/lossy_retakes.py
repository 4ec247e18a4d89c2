"""Capture sequences on a lossy GigE Vision fake and count retakes, failures and mispaired frames.

Run as ``python -m tests.harness.lossy_retakes N SYNC [LOSS]`` (repository root on ``PYTHONPATH``;
SYNC ``software``, ``booth`` or ``camera``; LOSS the fraction of stream packets the fake drops,
default 0.02): N sequences of ambient + 7 LEDs on the ``aravis-fake`` rig with
``lost_packet_ratio=LOSS``, each captured with ``retakes=100``. Prints one line: sequences
complete, retakes, failures (with their first error) and frames written under another step's
light (the rig renders each delivered frame under the levels of its trigger, so a frame's
rendered levels must be its step's). ``docs/steady-tests.md`` §1 runs it beside two busy loops.
"""

from __future__ import annotations

import collections
import logging
import sys
import tempfile
from pathlib import Path


class _CountRetakes(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.retakes = 0

    def emit(self, record: logging.LogRecord) -> None:
        if "again, with the" in record.getMessage():
            self.retakes += 1


def repeat(n: int, sync: str, loss: float = 0.02) -> str:
    """The summary line for ``n`` sequences."""
    from msflash.acquisition.plan import CapturePlan
    from msflash.acquisition.session.capture import run_capture
    from msflash.acquisition.session.rig import open_aravis_fake_rig
    from tests.acquisition.support.capture_doubles import Watch

    counter = _CountRetakes()
    capture_log = logging.getLogger("msflash.acquisition.session.engine")
    capture_log.addHandler(counter)
    capture_log.propagate = False  # the count, not a page of warnings
    complete = mispaired = 0
    failures: collections.Counter[str] = collections.Counter()
    try:
        for _ in range(n):
            plan = CapturePlan.ambient_then_each_led(7, 8_000.0, trigger=sync)  # type: ignore[arg-type]
            with open_aravis_fake_rig(lost_packet_ratio=loss) as rig, tempfile.TemporaryDirectory() as folder:

                def check(step, _frame, _entry) -> None:
                    nonlocal mispaired
                    used = rig.camera.rendered_levels[-1]
                    mispaired += any(abs(a - b) > 1e-4 for a, b in zip(used, step.led_levels, strict=True))

                try:
                    with rig.sequence_writer(Path(folder) / "s") as writer:
                        run_capture(rig.camera, rig.booth, plan, writer, (Watch(check),), retakes=100)
                        writer.finish()
                    complete += 1
                except Exception as err:  # noqa: BLE001 - counted and named in the summary
                    failures[f"{type(err).__name__}: {str(err)[:120]}"] += 1
    finally:
        capture_log.removeHandler(counter)
        capture_log.propagate = True
    first = f"; first: {failures.most_common(1)[0][0]}" if failures else ""
    return (
        f"{sync}, loss {loss:g}: {complete}/{n} sequences complete, {counter.retakes} retakes, "
        f"{sum(failures.values())} failed, {mispaired} frames mispaired{first}"
    )


if __name__ == "__main__":
    loss = float(sys.argv[3]) if len(sys.argv) > 3 else 0.02
    print(repeat(int(sys.argv[1]), sys.argv[2], loss))
