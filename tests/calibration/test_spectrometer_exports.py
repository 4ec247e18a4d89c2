"""``msflash calibrate leds`` on exports as the instruments write them (issue 29, item 5).

The exports come from an independent writer (``spectrometer_writers.py``): the paper's measured
LEDs seen through a CCD spectrometer with its own response, a fixed offset and a dark current
(about 100 counts of baseline), integration times that differ between LEDs and from the dark's,
averaging, and each program's quirks. The LED spectra msflash stores are compared with the truth
the writer used: energy ratios between LEDs and each LED's shape.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app import cli
from msflash.calibration.files import load_calibration
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID, Spectra
from tests.calibration.spectrometer_writers import FORMATS, Instrument, encoded, export_text

LEDS = ("led440", "led520", "led660")
TIMES_S = {"led440": 0.010, "led520": 0.005, "led660": 0.020}
"""Each LED its own integration time, as a lab sets them (the dim one longer)."""
DARK_TIME_S = 0.020


def run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(argv)
    return status, out.getvalue(), err.getvalue()


def _truth() -> Spectra:
    """The paper's LEDs (PR-715, energy), 380–800 nm, each scaled to a peak irradiance of its own."""
    leds = datasets.paper_leds().select([0, 3, 6]).replace(names=LEDS)  # the paper's 440, 520 and 660 nm LEDs
    scales = np.array([1.0, 0.6, 0.8])
    return leds.replace(values=leds.values / leds.values.max(axis=0) * scales)


def _irradiance(truth: Spectra, name: str, wavelengths: np.ndarray) -> np.ndarray:
    column = truth.values[:, truth.names.index(name)]
    return np.interp(wavelengths, truth.wavelengths_nm, column, left=0.0, right=0.0)


def _write_booth(
    folder: Path,
    form: str,
    *,
    dark: bool = True,
    times: dict[str, float] | None = None,
    dark_time: float | None = DARK_TIME_S,
    seed: int = 0,
    instrument: Instrument | None = None,
    **quirks,
) -> tuple[list[str], str | None, Instrument]:
    times = TIMES_S if times is None else times
    instrument = instrument or Instrument.typical(seed)
    rng = np.random.default_rng(seed + 1)
    truth = _truth()
    files = []
    for name in LEDS:
        time = times[name]
        # peaks of 4 000–20 000 counts
        irradiance = _irradiance(truth, name, instrument.wavelengths_nm) * 25000 / (4000 * 1.25 * 0.020)
        counts = instrument.counts(irradiance, time, 4, rng)
        text = export_text(form, instrument.wavelengths_nm, counts, time, 4, name=name, **quirks.get("text", {}))
        path = folder / f"{name}.txt"
        path.write_bytes(encoded(text, **quirks.get("bytes", {})))
        files.append(str(path))
    dark_path = None
    if dark:
        counts = instrument.counts(None, dark_time or 0.0, 16, rng)
        text = export_text(
            form, instrument.wavelengths_nm, counts, dark_time, 16, name="dark", **quirks.get("text", {})
        )
        dark_path = str(folder / "dark.txt")
        Path(dark_path).write_bytes(encoded(text, **quirks.get("bytes", {})))
    return files, dark_path, instrument


def _response_file(folder: Path, instrument: Instrument, per_count: bool = False) -> str:
    path = folder / "response.csv"
    if per_count:  # energy per count, as Ocean's irradiance calibration files give it
        rows = ["wavelength_nm,uJ/count"] + [
            f"{w:.4f},{1 / r:.9g}" for w, r in zip(instrument.wavelengths_nm, instrument.response)
        ]
    else:
        rows = ["wavelength_nm,counts_per_s_per_irradiance"] + [
            f"{w:.4f},{r:.9g}" for w, r in zip(instrument.wavelengths_nm, instrument.response)
        ]
    path.write_text("\n".join(rows) + "\n")
    return str(path)


def _energy_ratios(spectra: Spectra) -> np.ndarray:
    energy = spectra.values.sum(axis=0)
    return energy / energy[LEDS.index("led520")]


def _compare(stored: Spectra, truth: Spectra, energy_tol: float, shape_tol: float) -> None:
    expected = truth.resample(DEFAULT_GRID, outside="zero")
    np.testing.assert_allclose(_energy_ratios(stored), _energy_ratios(expected), rtol=energy_tol)
    shapes = stored.values / stored.values.max(axis=0)
    true_shapes = expected.values / expected.values.max(axis=0)
    assert np.max(np.abs(shapes - true_shapes)) < shape_tol


@pytest.mark.parametrize("form", FORMATS)
def test_each_format_with_a_dark_of_another_time_and_the_response_gives_the_true_energy(form, tmp_path):
    """Dark at 20 ms, LEDs at 5, 10 and 20 ms: the dark is scaled per LED, counts per second, ÷ response."""
    files, dark, instrument = _write_booth(tmp_path, form, seed=3)
    response = _response_file(tmp_path, instrument)
    status, out, err = run(
        [
            "calibrate",
            "leds",
            *files,
            "--dark",
            dark,
            "--spectrometer-response",
            response,
            "--out",
            str(tmp_path / "cal"),
            "--json",
        ]
    )
    assert status == 0, err
    calibration = load_calibration(tmp_path / "cal")
    section = calibration.leds
    assert "unit" not in section  # energy: the response was divided out
    assert [a["integration_time_s"] for a in section["acquisition"]] == pytest.approx([0.010, 0.005, 0.020])
    assert all(a["averages"] == 4 for a in section["acquisition"])
    assert section["counts_per_second"] is True and section["spectrometer_response"].startswith(response)
    scaled = [b for b in section["baselines"] if b["method"] == "dark export scaled to the integration time"]
    assert len(scaled) == 2 and "scaled (dark current ∝ time" in err  # 10 and 5 ms; 20 ms is the dark's own
    _compare(calibration.led_spectra, _truth(), energy_tol=0.01, shape_tol=0.02)


def test_without_the_response_counts_stay_counts_per_second(tmp_path, capsys):
    files, dark, instrument = _write_booth(tmp_path, "oceanview", seed=4)
    status, out, err = run(["calibrate", "leds", *files, "--dark", dark, "--out", str(tmp_path / "cal")])
    assert status == 0, err
    assert "LED spectra stored as spectrometer counts per second" in err
    calibration = load_calibration(tmp_path / "cal")
    assert calibration.leds["unit"] == "counts"
    assert json.loads((tmp_path / "cal" / "calibration.json").read_text())["leds"]["unit"] == "counts"
    assert any("LED spectra are spectrometer counts" in note for note in calibration.notes)
    # what they are: the irradiance times the spectrometer's response, per second
    truth = _truth()
    seen = truth.replace(
        values=truth.values * np.interp(truth.wavelengths_nm, instrument.wavelengths_nm, instrument.response)[:, None]
    )
    _compare(calibration.led_spectra, seen, energy_tol=0.01, shape_tol=0.02)
    # the same counts made energy by a response written as energy per count (inverted)
    response = _response_file(tmp_path, instrument, per_count=True)
    status, _, err = run(
        ["calibrate", "leds", *files, "--dark", dark, "--spectrometer-response", response, "--out", str(tmp_path / "e")]
    )
    assert status == 0, err
    _compare(load_calibration(tmp_path / "e").led_spectra, truth, energy_tol=0.01, shape_tol=0.02)


@pytest.mark.parametrize("form", ["oceanview", "avasoft", "spectrawiz", "thorlabs"])
def test_without_a_dark_the_baseline_is_measured_on_the_tail_with_a_warning(form, tmp_path):
    """The ~100-count baseline stayed in every LED (+40 % energy); now it is measured and said."""
    files, _, instrument = _write_booth(tmp_path, form, dark=False, seed=5)
    response = _response_file(tmp_path, instrument)
    status, _, err = run(
        ["calibrate", "leds", *files, "--spectrometer-response", response, "--out", str(tmp_path / "cal")]
    )
    assert status == 0, err
    assert err.count("warning: ") >= len(LEDS) and err.count("no dark given: a baseline of") == len(LEDS)
    calibration = load_calibration(tmp_path / "cal")
    assert [b["method"] for b in calibration.leds["baselines"]] == ["out-of-band tail"] * len(LEDS)
    # the measured LEDs' own low skirts (0.1–0.5 % of the peak out to 300 nm away) count as baseline: a few %
    _compare(calibration.led_spectra, _truth(), energy_tol=0.05, shape_tol=0.03)


def test_avasoft_uses_the_dark_it_stored(tmp_path):
    instrument = Instrument.typical(6)
    rng = np.random.default_rng(7)
    files = []
    for name in LEDS:
        time = TIMES_S[name]
        irradiance = _irradiance(_truth(), name, instrument.wavelengths_nm) * 25000 / (4000 * 1.25 * 0.020)
        stored = instrument.counts(None, time, 16, rng)
        text = export_text(
            "avasoft",
            instrument.wavelengths_nm,
            instrument.counts(irradiance, time, 4, rng),
            time,
            4,
            stored_dark=stored,
            decimal_comma=True,
            name=name,
        )
        (tmp_path / f"{name}.TRM.txt").write_bytes(encoded(text, crlf=True))
        files.append(str(tmp_path / f"{name}.TRM.txt"))
    status, _, err = run(
        [
            "calibrate",
            "leds",
            *files,
            "--spectrometer-response",
            _response_file(tmp_path, instrument),
            "--out",
            str(tmp_path / "cal"),
        ]
    )
    assert status == 0, err
    calibration = load_calibration(tmp_path / "cal")
    assert [b["method"] for b in calibration.leds["baselines"]] == ["dark column of the export"] * len(LEDS)
    assert calibration.leds["acquisition"][0]["instrument"] == "AvaSoft"
    _compare(calibration.led_spectra, _truth(), energy_tol=0.01, shape_tol=0.02)


@pytest.mark.parametrize(
    ("form", "quirks"),
    [
        ("oceanview", {"text": {"decimal_comma": True}, "bytes": {"crlf": True, "bom": True}}),
        ("thorlabs", {"text": {"decimal_comma": True}, "bytes": {"crlf": True}}),
        ("spectrasuite", {"bytes": {"encoding": "utf-16"}}),
        ("spectrawiz", {"bytes": {"crlf": True}}),
        ("avasoft", {"text": {"decimal_comma": True}, "bytes": {"bom": True}}),
    ],
)
def test_quirks_decimal_commas_bom_crlf_utf16(form, quirks, tmp_path):
    files, dark, instrument = _write_booth(tmp_path, form, seed=8, **quirks)
    status, _, err = run(
        [
            "calibrate",
            "leds",
            *files,
            "--dark",
            dark,
            "--spectrometer-response",
            _response_file(tmp_path, instrument),
            "--out",
            str(tmp_path / "cal"),
        ]
    )
    assert status == 0, err
    calibration = load_calibration(tmp_path / "cal")
    assert [a["integration_time_s"] for a in calibration.leds["acquisition"]] == pytest.approx([0.010, 0.005, 0.020])
    _compare(calibration.led_spectra, _truth(), energy_tol=0.01, shape_tol=0.02)


def _refused(argv: list[str]) -> str:
    status, out, err = run(argv)
    assert (status, out) == (2, ""), err
    assert err.count("\n") == 1 and err.startswith("msflash: error: ")
    return err


def test_bad_input_is_one_line(tmp_path):
    files, dark, _ = _write_booth(tmp_path, "plain", seed=9)
    out = str(tmp_path / "cal")
    # a --unit that contradicts the header
    (tmp_path / "ava").mkdir()
    avasoft, _, _ = _write_booth(tmp_path / "ava", "avasoft", dark=False)
    assert "--unit energy but the export's header says its values are counts" in _refused(
        ["calibrate", "leds", *avasoft, "--unit", "energy", "--out", out]
    )
    # a plain file stating its time without a unit
    text = Path(files[0]).read_text().replace("# integration_time_ms: 10", "# integration time: 10")
    Path(files[0]).write_text(text)
    err = _refused(["calibrate", "leds", *files, "--unit", "counts", "--dark", dark, "--out", out])
    assert "led440.txt:2: 'integration time: 10' states an integration time without a unit" in err
    # one LED with a time, another without
    Path(files[0]).write_text(text.replace("# integration time: 10\n", ""))
    err = _refused(["calibrate", "leds", *files, "--unit", "counts", "--dark", dark, "--out", out])
    assert "led440.txt: states no integration time but" in err
    # the CLI time fills in what a header does not state (the others keep their own)
    status, _, err = run(
        ["calibrate", "leds", *files, "--unit", "counts", "--dark", dark, "--integration-time-ms", "10", "--out", out]
    )
    assert status == 0, err
    assert [a["integration_time_s"] for a in load_calibration(out).leds["acquisition"]] == pytest.approx(
        [0.010, 0.005, 0.020]
    )
    assert "--no-dark exclude each other" in _refused(
        ["calibrate", "leds", *files[1:], "--dark", dark, "--no-dark", "--out", str(tmp_path / "other")]
    )


def test_raw_counts_without_dark_or_tail_are_refused_unless_no_dark(tmp_path):
    """An export that is all emission (a narrow window around the LED) has no tail to measure the baseline on."""
    instrument = Instrument.typical(10, start=625.0, stop=700.0, pixels=300)
    files, _, _ = _write_booth(tmp_path, "oceanview", dark=False, instrument=instrument)
    err = _refused(["calibrate", "leds", files[2], "--out", str(tmp_path / "cal")])
    assert "led660.txt: raw counts, no dark given and no out-of-band tail" in err and "--no-dark" in err
    # --no-dark takes an export as it is, and says so when its tail holds a baseline
    (tmp_path / "full").mkdir()
    files, _, _ = _write_booth(tmp_path / "full", "oceanview", dark=False)
    status, _, err = run(["calibrate", "leds", files[2], "--no-dark", "--out", str(tmp_path / "cal")])
    assert status == 0, err
    assert "warning: " in err and "--no-dark, but the out-of-band tail" in err and "kept as it is" in err
    assert load_calibration(tmp_path / "cal").leds["baselines"] == [{"method": "none (--no-dark)"}]


def test_a_dark_subtracted_export_is_said_to_be_one(tmp_path):
    """The instrument program subtracted the dark: tails at 0 ± noise, nothing subtracted, a note says so."""
    files, dark, instrument = _write_booth(tmp_path, "plain", seed=11)

    def table(path: str) -> np.ndarray:
        return np.array(
            [[float(c) for c in line.split(",")] for line in Path(path).read_text().splitlines() if line[:1].isdigit()]
        )

    dark_counts = table(dark)[:, 1]
    for file in files:
        rows = table(file)
        text = Path(file).read_text()
        head = [line for line in text.splitlines() if line.startswith("#") or line.startswith("wavelength")]
        body = [f"{w:.4f},{c - d:.3f}" for (w, c), d in zip(rows, dark_counts)]  # 20-ms dark: the 20-ms LED only
        Path(file).write_text("\n".join(head + body) + "\n")
    status, _, err = run(["calibrate", "leds", files[2], "--unit", "counts", "--out", str(tmp_path / "cal")])
    assert status == 0, err
    assert "already dark-corrected, nothing subtracted" in err
