"""``msflash run --rig sim --booth-firmware`` in every sync mode: the whole run against the firmware in simavr.

The booth is the reference firmware (its LED pins from the datasheet model in the harness), wired to
the simulated camera as on a real rig; the camera renders each row under the pins integrated over
its exposure window. One short run per mode (simavr pacing is the cost).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.led_controller.firmware_sim import toolchain_missing

pytestmark = pytest.mark.skipif(toolchain_missing() is not None, reason=str(toolchain_missing()))


@pytest.mark.parametrize("sync", ["host", "booth", "camera"])
def test_a_run_against_the_firmware(sync: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    code = main(["run", "--rig", "sim", "--booth-firmware", "--sync", sync, "--out", str(out)])
    stderr = capsys.readouterr().err
    assert code == 0, stderr[-2000:]
    sequence = json.loads((out / "sequence" / "sequence.json").read_text())
    roles = [frame["role"] for frame in sequence["frames"]]
    assert roles[0] == "ambient" and roles[-1] == "flash" and roles.count("led") == 7
    flash = sequence["frames"][-1]
    if sync == "host":
        # the booth dims by PWM here: the planner made the flash exposure whole PWM periods (or warned)
        period_us = 1e6 / (16e6 / 65536)
        whole = abs(flash["exposure_us"] / period_us - round(flash["exposure_us"] / period_us)) < 1e-6
        assert whole or "dims by PWM" in stderr
    else:
        # pulses: what each LED delivered is recorded, within 1 % of the level asked (or below 1e-3 of full)
        delivered = flash["delivered_levels"]  # a frame's extra keys sit beside its own
        for asked, got in zip(flash["led_levels"], delivered, strict=True):
            assert got == pytest.approx(asked, rel=0.01, abs=1e-3)
