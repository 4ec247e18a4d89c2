"""The hardware rig as a user opens it, without hardware: shared fixtures and the command line.

The Aravis in-process ``Fake_1`` camera by its device id on the ``fake`` interface (nothing is
broadcast) and the booth emulator's pty path as ``--port``. Used by the hardware-rig, camera-feature,
gain, calibration-reference and booth-adapter tests; the fixtures reach them through
``tests/acquisition/conftest.py``.

Fixtures
--------
``hw_calibration``
    A calibration directory of CSV files: the paper's 7 LEDs and a NikonD100's responsivities (energy).
``hw_booth_port``
    The booth emulator for those 7 LEDs served on a pty: its path is what ``--port`` gets.
``led_spectra_csv``
    The paper's 7 LED spectra as one CSV (the hardware rig needs them before it opens a device).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from msflash.acquisition.session.rigs.emulated_booth import emulator_for
from msflash.led_controller import serve_on_pty
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID, Spectra


def fake_camera_capture(port: str | Path, *options: str) -> list[str]:
    """``msflash capture`` on the Aravis ``Fake_1`` camera (fake interface only) with the booth at ``port``."""
    return ["capture", "--camera", "Fake_1", "--interfaces", "fake", "--port", str(port), *options]


def write_spectra_csv(path: Path, spectra: Spectra) -> Path:
    """``spectra`` as a ``wavelength_nm, name…`` CSV at ``path``."""
    lines = ["wavelength_nm," + ",".join(spectra.names)]
    lines += [f"{w:g}," + ",".join(f"{v:.6g}" for v in row) for w, row in zip(spectra.wavelengths_nm, spectra.values)]
    path.write_text("\n".join(lines) + "\n")
    return path


def paper_leds() -> Spectra:
    """The paper's 7 LEDs on the default grid."""
    return datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")


def nikon_d100() -> Spectra:
    """A NikonD100's responsivities on the default grid, in energy units."""
    return datasets.isetcam_camera("NikonD100").resample(DEFAULT_GRID, outside="zero").to_unit("energy")


@contextmanager
def booth_on_pty(leds: Spectra) -> Iterator[str]:
    """The booth emulator for ``leds`` served on a pty while the block runs; yields its path."""
    server = serve_on_pty(emulator_for(leds))
    try:
        yield server.port
    finally:
        server.close()


@pytest.fixture
def hw_calibration(tmp_path: Path) -> Path:
    """A calibration directory: the paper's 7 LEDs and a NikonD100's responsivities (energy units)."""
    directory = tmp_path / "calibration"
    directory.mkdir()
    write_spectra_csv(directory / "led_spectra.csv", paper_leds())
    write_spectra_csv(directory / "camera_responsivity.csv", nikon_d100())
    return directory


@pytest.fixture
def hw_booth_port(hw_calibration: Path) -> Iterator[str]:
    """The booth emulator (7 channels) served on a pty: its path is what ``--port`` gets."""
    leds = datasets.load_spectra_csv(hw_calibration / "led_spectra.csv", kind="spd", unit="energy")
    with booth_on_pty(leds) as port:
        yield port


@pytest.fixture
def led_spectra_csv(tmp_path: Path) -> Path:
    """The paper's 7 LED spectra as a CSV (the hardware rig needs them before it opens a device)."""
    return write_spectra_csv(tmp_path / "led_spectra.csv", paper_leds())
