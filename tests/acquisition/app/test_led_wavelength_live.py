"""The live page's ``peak_nm``, the sim booth's ``PEAKS`` and the sequence a rig writes give each LED one number
(processing/led_wavelength.py): the rest of the outputs are checked in test_export_validates.py."""

from __future__ import annotations

from pathlib import Path

from msflash.processing.led_wavelength import led_name
from tests.acquisition.support.live import live_server


def test_the_live_state_the_booth_and_the_sequence_header_agree(tmp_path: Path) -> None:
    with live_server(tmp_path / "runs") as server:
        leds = server.state_json()["leds"]
        rig = server.rig
        _, _, entries = rig.sequence_header()
        emulator = rig.emulator
        assert emulator is not None
        peaks = [led["peak_nm"] for led in leds]
        assert [led["name"] for led in leds] == [led_name(p) for p in peaks] == [e.name for e in entries]
        assert [e.peak_nm for e in entries] == peaks
        assert list(emulator.peaks_nm) == peaks  # what the booth states (INFO) in the sim rig
