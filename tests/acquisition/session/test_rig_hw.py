"""The hardware rig (``--rig hw``, implied by ``--camera``/``--port``) without hardware.

"Hardware" here is what a user would open: the Aravis in-process ``Fake_1`` camera by its device
id on the ``fake`` interface (nothing is broadcast) and the booth emulator's pty path as
``--port``. Failures use the Fake interface only and a pty nobody answers on.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.app.cli_common import UsageError
from msflash.acquisition.errors import RigOpenError
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.rig import HwRigOptions, open_rig
from msflash.acquisition.session.rigs.emulated_booth import emulator_for
from msflash.acquisition.session.rigs.hardware import hw_spectra
from msflash.led_controller import serve_on_pty
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID
from tests.acquisition.support.hw_rig import fake_camera_capture, write_spectra_csv

pytestmark = pytest.mark.aravis


@pytest.fixture
def silent_pty() -> Iterator[str]:
    """A pty path on which nothing answers (not a booth)."""
    master, slave = os.openpty()
    try:
        yield os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


def test_capture_on_fake_camera_and_emulated_booth(
    aravis: ModuleType, hw_calibration: Path, hw_booth_port: str, tmp_path: Path
) -> None:
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    out = tmp_path / "c"
    assert (
        main(
            fake_camera_capture(
                hw_booth_port, "--calibration", str(hw_calibration), "--exposure", "10000", "--out", str(out)
            )
        )
        == 0
    )
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    assert [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 7
    assert sequence.camera.model == "Fake" and sequence.camera.cfa is None
    assert "replicated" in sequence.camera.extra["channels"]
    assert sequence.camera_responsivities() is not None
    assert sequence.leds[0].name == "led440"
    ids = [f.extra["frame_id"] for f in sequence.frames]
    assert all(b - a == 1 for a, b in itertools.pairwise(ids))
    pixels = sequence.load_frame(1)
    assert pixels.ndim == 3 and np.array_equal(pixels[..., 0], pixels[..., 1])
    assert sequence.frames[0].exposure_us == pytest.approx(10_000)


def test_rig_hw_with_csv_files_and_led_off_at_close(
    aravis: ModuleType, hw_calibration: Path, hw_booth_port: str
) -> None:
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    with open_rig(
        "hw",
        HwRigOptions(
            camera="Fake_1", interfaces="fake", port=hw_booth_port, led_spectra=hw_calibration / "led_spectra.csv"
        ),
    ) as rig:
        assert rig.name == "hw" and rig.booth.info.channels == 7
        assert rig.camera_responsivities is None and "flash solvers" in rig.camera_extra["responsivity_note"]
        low, high = rig.camera.exposure_range_us
        assert 0 <= low < high
        rig.booth.set_levels([1.0] + [0.0] * 6)
    # closed: a second open of the same devices works (the camera and the port were released)
    with open_rig(
        "hw", HwRigOptions(camera="Fake_1", interfaces="fake", port=hw_booth_port, calibration=hw_calibration)
    ) as rig:
        assert rig.camera_responsivities is not None


def test_every_device_failure_is_listed(aravis: ModuleType, hw_calibration: Path, silent_pty: str) -> None:
    with pytest.raises(RigOpenError) as caught:
        open_rig("hw", HwRigOptions(camera="SN123", interfaces="fake", port=silent_pty, calibration=hw_calibration))
    message = str(caught.value)
    assert message.startswith("rig 'hw': camera 'SN123': not found on fake (found: Fake_1")
    assert f"booth: {silent_pty}: no answer within " in message and "of opening the port" in message
    assert "auto-reset" in message  # what a silent Mega usually means


def test_cli_failure_exits_1_with_one_line(
    aravis: ModuleType, hw_calibration: Path, silent_pty: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    status = main(
        [
            "capture",
            "--camera",
            "SN123",
            "--interfaces",
            "fake",
            "--port",
            silent_pty,
            "--calibration",
            str(hw_calibration),
            "--out",
            str(tmp_path / "x"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1
    assert err[-1].startswith("msflash: error: rig 'hw': camera 'SN123'") and "booth" in err[-1]


def test_no_camera_without_an_id_lists_what_was_found(
    aravis: ModuleType, hw_calibration: Path, hw_booth_port: str
) -> None:
    """No --camera: the single camera on the interfaces is taken; on fake there is exactly one."""
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    with open_rig("hw", HwRigOptions(interfaces="fake", port=hw_booth_port, calibration=hw_calibration)) as rig:
        assert rig.camera.info.extra["device_id"] == "Fake_1"


def test_booth_channel_count_must_match_the_spectra(aravis: ModuleType, hw_calibration: Path, tmp_path: Path) -> None:
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero").select([0, 1, 2])
    server = serve_on_pty(emulator_for(leds))
    try:
        with pytest.raises(RigOpenError, match=r"3 channels .* but the LED spectra have 7"):
            open_rig(
                "hw", HwRigOptions(camera="Fake_1", interfaces="fake", port=server.port, calibration=hw_calibration)
            )
    finally:
        server.close()


def test_the_sim_rig_checks_its_external_booth_as_the_hw_rig_does(monkeypatch: pytest.MonkeyPatch) -> None:
    """Both rigs open a booth on a port through the one ``external_booth.open_checked_booth``: the sim rig's
    ``--booth-port`` with a booth of 3 channels for its 7 LEDs is refused in its own words, the booth's LEDs off."""
    from msflash.acquisition.session import external_booth
    from msflash.acquisition.session.rigs.sim import open_sim_rig

    opened: list[str] = []
    real = external_booth.open_checked_booth

    def counted(port, *args):  # noqa: ANN001, ANN202 — the module's own opener, counted
        opened.append(port)
        return real(port, *args)

    monkeypatch.setattr(external_booth, "open_checked_booth", counted)
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero").select([0, 1, 2])
    emulator = emulator_for(leds)
    server = serve_on_pty(emulator)
    try:
        with pytest.raises(RigOpenError, match=r"3 channels .* but the simulated LEDs are 7 .*expected one channel"):
            open_sim_rig(booth_port=server.port)
        assert opened == [server.port] and list(emulator.levels) == [0.0, 0.0, 0.0]
    finally:
        server.close()


def test_a_booth_of_another_protocol_version_is_one_error_line(
    aravis: ModuleType, hw_calibration: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    from msflash.led_controller import BoothEmulator

    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
    default = emulator_for(leds)
    newer = BoothEmulator(names=default.names, peaks_nm=default.peaks_nm, firmware="booth-2.0", protocol=2)
    with serve_on_pty(newer) as server:
        status = main(
            fake_camera_capture(server.port, "--calibration", str(hw_calibration), "--out", str(tmp_path / "x"))
        )
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1 and len(err) == 1
    assert err[0].startswith(
        f"msflash: error: rig 'hw': booth: {server.port}: booth firmware booth-2.0 speaks "
        "booth protocol 2; expected protocol 1"
    )


def test_spectra_are_required_before_any_device_opens(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(UsageError, match="--calibration DIR or --led-spectra"):
        hw_spectra()
    assert main(["capture", "--port", "/dev/null", "--out", str(tmp_path / "x")]) == 2
    assert "LED spectra are needed" in capsys.readouterr().err
    with pytest.raises(UsageError, match="no calibration.json or led_spectra.csv"):
        hw_spectra(calibration=tmp_path)


def test_rig_sim_with_a_camera_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["capture", "--rig", "sim", "--camera", "SN1", "--out", str(tmp_path / "x")]) == 2
    assert "--rig hw" in capsys.readouterr().err


def test_calibration_directory_from_msflash_calibrate(tmp_path: Path) -> None:
    """A ``calibration.json`` directory (the calibration package's format) gives both spectra."""
    files = pytest.importorskip("msflash.calibration.files")
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
    camera = datasets.isetcam_camera("NikonD100").resample(DEFAULT_GRID, outside="zero")
    files.save_calibration(files.CalibrationSet(led_spectra=leds, camera_responsivities=camera), tmp_path / "cal")
    found_leds, found_camera, _ = hw_spectra(tmp_path / "cal")
    assert found_leds.count == 7 and found_leds.unit == "energy"
    assert found_camera is not None and found_camera.count == 3 and found_camera.unit == "energy"
    # a file on the command line wins over the calibration's section
    only = write_spectra_csv(tmp_path / "three.csv", leds.select([0, 1, 2]))
    assert hw_spectra(tmp_path / "cal", led_spectra=only)[0].count == 3
