"""Every file a ``msflash calibrate`` command writes is read by every command that reads calibrations.

Issue 20, item 6: ``calibrate leds`` on dark-subtracted spectrometer exports wrote a ``leds.csv``
with small negative values that ``calibrate camera`` and ``flash --calibration`` then refused
("cal/leds.csv: negative values"). The property test generates spectrometer exports (grids,
headers, separators, LED peaks, dark-subtraction noise that leaves negatives, a separate dark
file or not) and runs ``calibrate leds`` → ``calibrate camera`` → ``flash --calibration`` →
``estimate --calibration`` through the real entry point (``acquisition.cli.main`` in process).
The dark and linearity writers are checked the same way on a recorded sequence.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msflash.acquisition.app import cli
from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.calibration.files import load_calibration
from msflash.processing import datasets
from msflash.processing.negative_values import PEAK_FRACTION
from msflash.processing.spectra import DEFAULT_GRID

SEQUENCE = Path(__file__).resolve().parents[1] / "data" / "sequences" / "sim-macbeth-fluorescent"
LED_PEAKS_NM = (440.0, 480.0, 500.0, 520.0, 596.0, 636.0, 660.0)
"""The sequence's LEDs (``led440`` … ``led660``): the exports are named after them."""


def run(argv: list[str]) -> tuple[int, str, str]:
    """``msflash ARGV`` in process: status, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(argv)
    return status, out.getvalue(), err.getvalue()


@dataclass(frozen=True)
class ExportStyle:
    """How an instrument writes its export."""

    header: str
    """``plain``, ``named`` (a column header line), ``ocean`` (Ocean Optics block) or ``comments``."""
    separator: str
    """``\\t``, ``,``, ``;`` (with decimal commas) or `` ``."""


def export_text(wavelengths: np.ndarray, values: np.ndarray, style: ExportStyle) -> str:
    """A spectrometer export of ``values`` in ``style``."""

    def number(v: float) -> str:
        text = f"{v:.9g}"
        return text.replace(".", ",") if style.separator == ";" else text

    rows = [f"{number(w)}{style.separator}{number(v)}" for w, v in zip(wavelengths, values, strict=True)]
    head = {
        "plain": [],
        "named": [f"Wavelength (nm){style.separator}Irradiance"],
        "ocean": ["Spectrometer: USB4000", ">>>>>Begin Spectral Data<<<<<"],
        "comments": ["# PR-715", "% integration 100 ms", "nm W/sr/m2"],
    }[style.header]
    tail = [">>>>>End Spectral Data<<<<<"] if style.header == "ocean" else []
    return "\n".join([*head, *rows, *tail]) + "\n"


@st.composite
def booth_exports(draw: st.DrawFn) -> dict:
    """Seven LED exports (and maybe a dark one) as a real booth's spectrometer gives them."""
    start = draw(st.floats(300.0, 395.0))
    stop = draw(st.floats(705.0, 1000.0))
    step = draw(st.floats(0.2, 2.0))
    n = int((stop - start) / step)
    index = np.arange(n, dtype=float)
    curvature = draw(st.sampled_from([0.0, -2e-5, 3e-5]))  # a CCD's pixel-to-wavelength polynomial
    wavelengths = start + step * index + curvature * step * index**2
    wavelengths = wavelengths[wavelengths <= stop]
    style = ExportStyle(
        draw(st.sampled_from(["plain", "named", "ocean", "comments"])), draw(st.sampled_from(["\t", ",", ";", " "]))
    )
    noise = draw(st.floats(0.0005, 0.03))  # dark-subtraction noise, relative to the peak
    separate_dark = draw(st.booleans())
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    scale = draw(st.floats(1e-4, 1e4))  # counts, W/m²/nm, µW/cm²/nm: any scale
    baseline = 100.0 * scale
    exports: dict[str, str] = {}
    for peak in LED_PEAKS_NM:
        centre = peak + rng.uniform(-8.0, 8.0)
        width = rng.uniform(6.0, 20.0)
        height = rng.uniform(0.3, 1.0)
        emission = height * np.exp(-0.5 * ((wavelengths - centre) / width) ** 2) * scale
        if separate_dark:  # raw counts on an offset; the dark file subtracted by --dark
            values = baseline + emission + rng.normal(0.0, noise * scale, wavelengths.size)
        else:  # the instrument software subtracted its dark: noise about 0, half of it negative
            values = (
                emission
                + rng.normal(0.0, noise * scale, wavelengths.size)
                - rng.normal(0.0, noise * scale, wavelengths.size)
            )
        exports[f"led{int(peak)}"] = export_text(wavelengths, values, style)
    dark = (
        export_text(wavelengths, baseline + rng.normal(0.0, noise * scale, wavelengths.size), style)
        if separate_dark
        else None
    )
    return {"exports": exports, "dark": dark, "unit": draw(st.sampled_from(["energy", "photons"]))}


# Health checks judge the generator (its speed, its data size) and fire on a loaded machine; with
# warnings as errors one replaced the assertion it interrupted. Here they are all off, and a
# failure prints its reproduction blob. The exports' noise stays within the rule's noise model
# (processing/negative_values.py, noise_sigmas): a column of Gaussian noise is refused with
# probability about FALSE_REFUSAL.
@settings(max_examples=5, deadline=None, suppress_health_check=list(HealthCheck), print_blob=True)
@given(booth=booth_exports())
def test_what_calibrate_writes_every_calibration_reader_accepts(booth: dict, tmp_path_factory) -> None:
    work = tmp_path_factory.mktemp("booth")
    files = []
    for name, text in booth["exports"].items():
        (work / f"{name}.txt").write_text(text, encoding="utf-8")
        files.append(str(work / f"{name}.txt"))
    dark = []
    if booth["dark"] is not None:
        (work / "dark.txt").write_text(booth["dark"], encoding="utf-8")
        dark = ["--dark", str(work / "dark.txt")]
    cal = str(work / "cal")

    status, out, err = run(["calibrate", "leds", *files, *dark, "--unit", booth["unit"], "--out", cal, "--json"])
    assert status == 0, err
    payload = json.loads(out)
    written = load_calibration(cal)
    assert written.led_spectra.names == tuple(f"led{int(p)}" for p in LED_PEAKS_NM)
    assert np.all(written.led_spectra.values >= 0) and written.notes == ()  # nothing left for a reader to clip
    for item in payload["clipped_negatives"]:  # what was clipped is reported, per LED, as noise
        assert item["count"] > 0 and -item["tolerance"] <= item["most_negative"] < 0
    assert payload["clipped_negatives"] == written.leds["clipped_negatives"]
    # The exports carry negatives (about half of the tails): the report must show them, on stderr too.
    assert len(payload["clipped_negatives"]) == len(LED_PEAKS_NM)
    assert err.count("clipped to 0 as noise") == len(LED_PEAKS_NM)

    status, _, err = run(["calibrate", "camera", "--simulate", "--method", "smoothness", "--out", cal, "--json"])
    assert status == 0, err
    both = load_calibration(cal)
    np.testing.assert_array_equal(both.led_spectra.values, written.led_spectra.values)  # kept as written

    for argv in (["flash", str(SEQUENCE), "--mode", "complementary"], ["estimate", str(SEQUENCE)]):
        status, out, err = run([*argv, "--json", "--calibration", cal])
        assert status == 0, err
        assert f"LED spectra from calibration {both.id}" in err and "clipped" not in err
        assert json.loads(out)


def test_a_leds_csv_with_negative_noise_from_an_older_msflash_is_read_clipped(tmp_path: Path) -> None:
    """What booths already have on disk: ``leds.csv`` holding the negatives; read with a note, not refused."""
    cal = tmp_path / "cal"
    # The paper's LEDs under the names the recorded sequence gives them (recorded before they were named
    # after their measured peaks).
    names = tuple(json.loads((SEQUENCE / "sequence.json").read_text())["leds"][k]["name"] for k in range(7))
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero").replace(names=names)
    rows = ["wavelength_nm," + ",".join(leds.names)]
    noisy = leds.values.copy()
    noisy[0, 2] = -0.02 * noisy[:, 2].max()  # noise below zero in led500's tail, within the rule
    rows += [f"{w:g}," + ",".join(repr(float(v)) for v in row) for w, row in zip(leds.wavelengths_nm, noisy)]
    cal.mkdir()
    (cal / "leds.csv").write_text("\n".join(rows) + "\n")
    (cal / "calibration.json").write_text(
        json.dumps(
            {
                "format": "msflash-calibration",
                "version": 1,
                "id": "cal-old",
                "leds": {"file": "leds.csv", "unit": "energy", "names": list(leds.names)},
            }
        )
    )
    status, out, err = run(["estimate", str(SEQUENCE), "--json", "--calibration", str(cal)])
    assert status == 0, err
    assert "leds.csv: column 'led500': 1 negative value(s)" in err and "clipped to 0 as noise" in err
    assert load_calibration(cal).led_spectra.values.min() == 0.0
    status, _, err = run(["calibrate", "camera", "--simulate", "--method", "smoothness", "--out", str(cal)])
    assert status == 0, err
    assert np.all(np.loadtxt(cal / "leds.csv", delimiter=",", skiprows=2) >= 0)  # written back clipped

    noisy[0, 2] = -2 * PEAK_FRACTION * noisy[:, 2].max()  # no noise: refused naming file, column, wavelength, value
    rows = rows[:1] + [f"{w:g}," + ",".join(repr(float(v)) for v in row) for w, row in zip(leds.wavelengths_nm, noisy)]
    (cal / "leds.csv").write_text("\n".join(rows) + "\n")
    status, out, err = run(["flash", str(SEQUENCE), "--mode", "matching", "--calibration", str(cal)])
    assert (status, out) == (2, "")
    assert err.count("\n") == 1 and "leds.csv: column 'led500' at 400 nm is -" in err
    assert "expected a non-negative value, or measurement noise down to" in err


def test_a_dark_subtracted_twice_is_refused_by_calibrate_leds(tmp_path: Path) -> None:
    w = np.arange(350.0, 800.0, 0.5)
    rng = np.random.default_rng(3)
    led = np.exp(-0.5 * ((w - 520) / 12) ** 2) + rng.normal(0.0, 0.002, w.size) - 0.1  # an offset, not noise
    (tmp_path / "led520.txt").write_text(export_text(w, led, ExportStyle("named", "\t")))
    status, out, err = run(["calibrate", "leds", str(tmp_path / "led520.txt"), "--out", str(tmp_path / "cal")])
    assert (status, out) == (2, "") and err.count("\n") == 1
    assert re.search(r"led520\.txt:2: column 'Irradiance' at 350 nm is -0\.(09|10)\d*; expected a non-negative", err)
    assert "dark subtracted twice" in err
    assert not (tmp_path / "cal" / "leds.csv").exists()


def _dark_and_linearity_sequence(directory: Path) -> Path:
    """Dark frames and a uniform target under one light (the ambient) at five exposures, 16-bit RGB."""
    rng = np.random.default_rng(0)
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
    camera = SequenceCamera("test camera", "0001", "RGB16", None, 64.0, 65535.0)
    writer = SequenceWriter(
        directory,
        wavelengths_nm=DEFAULT_GRID.wavelengths_nm,
        spectral_unit="energy",
        camera=camera,
        leds=[SequenceLed(n, leds.column(n)) for n in leds.names],
    )
    off = (0.0,) * leds.count
    for _ in range(3):
        writer.add_frame(np.rint(rng.normal(64.0, 2.0, (24, 32, 3))).astype(np.uint16), "dark", off, 1000.0)
    for exposure in (1000.0, 2000.0, 4000.0, 8000.0, 16000.0):
        signal = 64.0 + 2.0 * exposure * np.array([1.0, 0.8, 0.5])
        pixels = rng.normal(signal, 3.0, (24, 32, 3))
        writer.add_frame(np.rint(np.clip(pixels, 0, 65535)).astype(np.uint16), "ambient", off, exposure)
    writer.finish()
    return directory


def test_dark_and_linearity_round_trip_into_their_readers(tmp_path: Path) -> None:
    sequence = _dark_and_linearity_sequence(tmp_path / "seq")
    cal = str(tmp_path / "cal")
    status, out, err = run(["calibrate", "dark", str(sequence), "--out", cal, "--json"])
    assert status == 0, err
    dark = json.loads(out)
    np.testing.assert_allclose(dark["black_level"], 64.0, atol=0.5)
    status, out, err = run(["calibrate", "linearity", str(sequence), "--out", cal, "--json"])  # reads the dark
    assert status == 0, err
    linearity = json.loads(out)
    assert linearity["max_relative_deviation"] < 0.01
    calibration = load_calibration(cal)
    assert calibration.dark["black_level"] == dark["black_level"]
    assert calibration.linearity["slope_dn_per_exposure"] == linearity["slope_dn_per_exposure"]
    assert run(["calibrate", "camera", "--simulate", "--method", "smoothness", "--out", cal])[0] == 0
    kept = load_calibration(cal)  # sections it does not measure are kept, and read back
    assert (kept.dark, kept.linearity) == (calibration.dark, calibration.linearity)
    status, out, err = run(["flash", str(SEQUENCE), "--mode", "complementary", "--json", "--calibration", cal])
    assert status == 0, err
    assert f"camera responsivities from calibration {kept.id}" in err
