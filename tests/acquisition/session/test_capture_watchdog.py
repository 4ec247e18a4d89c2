"""The booth's watchdog never fires in the middle of a sequence the host is running.

The watchdog (``docs/booth-protocol.md`` §7) switches the LEDs off and aborts the table when the
host sends nothing for its period (3 s at power-up, or whatever a user set). A booth-master table
runs without a command from the host, and a host-paced step is silent for its whole exposure: a
sequence longer than the watchdog was aborted half way, and a long host-paced LED exposure was
partly dark. Here on the sim rig (SimulatedCamera + booth emulator on a real pty) with the
watchdog set short through the driver, as a user may set it.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.booth_guard import host_silence_s
from msflash.acquisition.session.capture import preview_frames, run_capture
from msflash.acquisition.session.rig import Rig, open_sim_rig
from msflash.led_controller import protocol
from tests.helpers import levels_close

SHORT_WATCHDOG_S = 0.2


@pytest.fixture
def sim_rig():
    with open_sim_rig(n_leds=4, seed=5) as rig:
        rig.booth.set_watchdog(SHORT_WATCHDOG_S)
        yield rig


class _ExposingCamera:
    """The sim camera with exposures that take their time, as a real camera's do.

    ``SimulatedCamera`` renders at once when triggered; here ``trigger()`` first waits the step's
    exposure, so the LED levels the frame is rendered with are the booth's at the *end* of the
    exposure (what a real sensor would have integrated until then).
    """

    def __init__(self, camera) -> None:  # noqa: ANN001 - the sim rig's SimulatedCamera
        self._camera = camera
        self._plan: CapturePlan | None = None
        self._next = 0

    def prepare(self, plan: CapturePlan) -> None:
        self._plan, self._next = plan, 0
        self._camera.prepare(plan)

    def trigger(self) -> None:
        assert self._plan is not None
        time.sleep(self._plan.steps[self._next].exposure_us * 1e-6)
        self._next += 1
        self._camera.trigger()

    def __getattr__(self, name: str):  # start, next_frame, stop, info…
        return getattr(self._camera, name)


def test_a_booth_master_table_longer_than_the_watchdog_runs_to_the_end(sim_rig: Rig, tmp_path: Path) -> None:
    plan = CapturePlan.ambient_then_each_led(4, 40_000.0, trigger="booth")  # 5 periods of 45 ms: > 0.2 s
    assert host_silence_s(plan) > SHORT_WATCHDOG_S
    with sim_rig.sequence_writer(tmp_path / "sequence") as writer:
        written = run_capture(sim_rig.camera, sim_rig.booth, plan, writer)
    assert len(written) == len(plan.steps) and read_sequence(tmp_path / "sequence").complete
    assert sim_rig.camera.rendered_levels == tuple(step.led_levels for step in plan.steps)
    assert sim_rig.booth.pending_events() == []  # no WDOG event: the LEDs were never switched off
    status = sim_rig.booth.status()
    assert status.watchdog_s == SHORT_WATCHDOG_S  # set back after the sequence
    assert levels_close(status.levels, (0.0,) * 4)


def test_a_host_paced_exposure_longer_than_the_watchdog_is_lit_to_its_end(sim_rig: Rig, tmp_path: Path) -> None:
    steps = CapturePlan.ambient_then_each_led(4, 300_000.0).steps[:3]  # ambient, led:1, led:2; 0.3 s each
    plan = CapturePlan(steps)
    camera = _ExposingCamera(sim_rig.camera)
    with sim_rig.sequence_writer(tmp_path / "sequence") as writer:
        run_capture(camera, sim_rig.booth, plan, writer)
    # Each LED frame saw its LED on at the end of its exposure (the watchdog had switched it off).
    assert sim_rig.camera.rendered_levels == tuple(step.led_levels for step in plan.steps)
    assert sim_rig.booth.pending_events() == []
    assert sim_rig.booth.status().watchdog_s == SHORT_WATCHDOG_S


def test_exposure_previews_are_covered_too(sim_rig: Rig) -> None:
    plan = CapturePlan.single((0.0, 1.0, 0.0, 0.0), 300_000.0, role="led")
    frames = preview_frames(_ExposingCamera(sim_rig.camera), sim_rig.booth, plan)
    assert len(frames) == 1 and sim_rig.camera.rendered_levels == ((0.0, 1.0, 0.0, 0.0),)
    assert sim_rig.booth.status().watchdog_s == SHORT_WATCHDOG_S


def test_a_long_enough_or_disabled_watchdog_is_left_alone(tmp_path: Path) -> None:
    """No WDOG traffic when the watchdog already covers the sequence (the usual short one) or is off."""
    plan = CapturePlan.ambient_then_each_led(4, 10_000.0, trigger="booth")
    for watchdog_s in (0.0, 3.0):
        transcript = tmp_path / f"booth-{watchdog_s:g}.txt"
        with open_sim_rig(n_leds=4, seed=5, log_serial=transcript) as rig:
            rig.booth.set_watchdog(watchdog_s)
            with rig.sequence_writer(tmp_path / f"sequence-{watchdog_s:g}") as writer:
                run_capture(rig.camera, rig.booth, plan, writer)
        requests = [line for line in transcript.read_text().splitlines() if line.startswith(">")]
        assert sum(":WDOG " in line for line in requests) == 1  # the test's own


def test_a_lost_link_mid_sequence_is_the_error_reported(tmp_path: Path) -> None:
    """The pty closes mid-sequence (the booth unplugged): the error is the lost link during the ``SET``
    that failed — not a second one from switching off (``OFF``) or setting the watchdog back on the
    dead port while leaving the capture and the rig — and the frames before stay on disk."""
    from msflash.led_controller import BoothError, PtyBoothServer

    with pytest.raises(BoothError) as caught, open_sim_rig(n_leds=4, seed=5) as rig:
        rig.booth.set_watchdog(SHORT_WATCHDOG_S)
        server = next(c.__self__ for c in rig._closers if isinstance(getattr(c, "__self__", None), PtyBoothServer))
        camera = _ExposingCamera(rig.camera)
        original = camera.trigger

        def trigger_then_unplug() -> None:
            original()
            if camera._next == 2:
                server.close()  # the booth unplugged

        camera.trigger = trigger_then_unplug  # type: ignore[method-assign]
        with rig.sequence_writer(tmp_path / "sequence") as writer:
            run_capture(camera, rig.booth, CapturePlan.ambient_then_each_led(4, 40_000.0), writer)
    assert "serial link lost during SET" in str(caught.value)
    assert len(read_sequence(tmp_path / "sequence").frames) == 2


def test_a_frame_the_watchdog_darkened_is_refused_not_kept(
    sim_rig: Rig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A host that stalls beyond its planned silence (here: the plan's silence taken as nil, so the
    watchdog is not raised) lets the watchdog switch the LED off mid-exposure: host paced, the next
    SET would just work, so the dark LED frame must be refused by name, not written as good data."""
    from msflash.acquisition.errors import CaptureError
    from msflash.acquisition.session import booth_guard

    monkeypatch.setattr(booth_guard, "host_silence_s", lambda plan: 0.0)
    plan = CapturePlan(CapturePlan.ambient_then_each_led(4, 300_000.0).steps[:3])
    with pytest.raises(CaptureError) as caught, sim_rig.sequence_writer(tmp_path / "sequence") as writer:
        run_capture(_ExposingCamera(sim_rig.camera), sim_rig.booth, plan, writer)
    assert str(caught.value).startswith("step 1 (led:1): the booth's watchdog switched the LEDs off during this frame")
    assert sim_rig.camera.rendered_levels[1] == (0.0,) * 4  # it was indeed exposed dark
    assert [f.role for f in read_sequence(tmp_path / "sequence").frames] == ["ambient"]


def test_an_unplugged_booth_through_the_cli_says_it_once_plus_the_leds_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """msflash capture with the booth's pty closed after two frames: exit 1, the error line is the lost link
    during SET, and the only diagnostics shown by default are the driver noticing it and the warning that
    the LEDs could not be confirmed off — not a second failure about OFF from closing the rig."""
    from msflash.acquisition.app import rig_choice
    from msflash.acquisition.app.cli import main
    from msflash.led_controller import PtyBoothServer

    real_open = rig_choice.open_rig

    def open_then_unplug_at_frame_3(spec, options=None):  # noqa: ANN001 - open_rig's signature
        rig = real_open(spec, options)
        server = next(c.__self__ for c in rig._closers if isinstance(getattr(c, "__self__", None), PtyBoothServer))
        real_next, count = rig.camera.next_frame, [0]

        def next_frame(timeout_s: float):  # noqa: ANN202 - the camera's
            count[0] += 1
            if count[0] == 3:
                server.close()  # the booth unplugged
            return real_next(timeout_s)

        rig.camera.next_frame = next_frame
        return rig

    monkeypatch.setattr(rig_choice, "open_rig", open_then_unplug_at_frame_3)
    status = main(["capture", "--exposure-us", "5000", "--out", str(tmp_path / "x")])
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert status == 1
    assert len(errors) == 1 and errors[0].startswith("msflash: error: ") and "serial link lost during SET" in errors[0]
    shown = [record.getMessage() for record in caplog.records if record.levelno >= logging.WARNING]
    assert len(shown) == 2  # in either order: the driver's reader thread notices the closed pty on its own
    assert sum(m.startswith("LEDs not confirmed off") for m in shown) == 1
    assert sum(": serial link lost: " in m for m in shown) == 1


def test_a_watchdog_event_from_before_the_sequence_does_not_refuse_its_frames(sim_rig: Rig, tmp_path: Path) -> None:
    """LEDs left on and forgotten before the capture: the watchdog switched them off (its WDOG event is
    queued); the sequence that follows is not blamed for it."""
    sim_rig.booth.set_levels((0.5, 0.0, 0.0, 0.0))
    booth = sim_rig.booth
    with booth._events_cv:  # the 0.2 s watchdog fires and its event is queued in the driver, not yet taken
        queued = booth._events_cv.wait_for(
            lambda: any(getattr(e, "kind", None) == protocol.Event.WATCHDOG for e in booth._events), timeout=60.0
        )
    assert queued and sim_rig.emulator.levels == (0.0,) * 4
    plan = CapturePlan.ambient_then_each_led(4, 10_000.0)
    with sim_rig.sequence_writer(tmp_path / "sequence") as writer:
        assert len(run_capture(sim_rig.camera, sim_rig.booth, plan, writer)) == len(plan.steps)
