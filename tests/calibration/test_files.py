"""Calibration files: round trip, merging sections, version refusal, errors naming file and field."""

from __future__ import annotations

import json

import numpy as np
import pytest

from msflash.calibration.errors import CalibrationError
from msflash.calibration.files import CalibrationSet, load_calibration, load_or_new, save_calibration
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID


def full_set():
    leds = datasets.paper_leds().resample(DEFAULT_GRID, outside="zero")
    camera = datasets.isetcam_camera("NikonD100").resample(DEFAULT_GRID, outside="zero")
    return CalibrationSet(
        led_spectra=leds,
        leds={"peaks_nm": [440.0] * 7, "relative_power": [1.0] * 7},
        camera_responsivities=camera,
        camera={"method": "pca_prior"},
        dark={"black_level": [64.0, 64.5, 63.9], "read_noise_dn": [2.0, 2.0, 2.0]},
        linearity={"max_relative_deviation": 0.001, "saturation_level": 65535.0},
        extra={"site": "booth A"},
    )


def test_round_trip(tmp_path):
    original = full_set()
    save_calibration(original, tmp_path / "cal")
    loaded = load_calibration(tmp_path / "cal")
    assert loaded.id == original.id and loaded.extra == {"site": "booth A"}
    np.testing.assert_allclose(loaded.led_spectra.values, original.led_spectra.values, rtol=1e-15)
    np.testing.assert_allclose(loaded.camera_responsivities.values, original.camera_responsivities.values, rtol=1e-15)
    assert loaded.led_spectra.names == original.led_spectra.names
    assert loaded.camera_responsivities.unit == "photons"
    assert loaded.dark == original.dark and loaded.linearity == original.linearity
    assert loaded.leds["relative_power"] == [1.0] * 7 and loaded.camera == {"method": "pca_prior"}


def test_update_keeps_other_sections(tmp_path):
    save_calibration(full_set(), tmp_path)
    before = load_or_new(tmp_path)
    after = before.updated(dark={"black_level": [1.0, 2.0, 3.0]})
    save_calibration(after, tmp_path)
    loaded = load_calibration(tmp_path)
    assert loaded.id != before.id and loaded.dark["black_level"] == [1.0, 2.0, 3.0]
    assert loaded.led_spectra is not None and loaded.camera_responsivities is not None
    assert load_or_new(tmp_path / "new").led_spectra is None


def edit(tmp_path, change):
    save_calibration(full_set(), tmp_path)
    path = tmp_path / "calibration.json"
    document = json.loads(path.read_text())
    change(document)
    path.write_text(json.dumps(document))
    return path


def test_newer_version_refused(tmp_path):
    edit(tmp_path, lambda d: d.update(version=3))
    with pytest.raises(CalibrationError, match=r"calibration\.json: field 'version' is 3; .*upgrade msflash"):
        load_calibration(tmp_path)


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda d: d.update(format="other"), r"field 'format' is 'other'"),
        (lambda d: d.update(version="1"), r"field 'version' is '1'"),
        (lambda d: d.update(id=""), r"field 'id'"),
        (lambda d: d.update(leds=[1]), r"field 'leds' is a list; expected an object"),
        (lambda d: d["leds"].update(unit="watts"), r"field 'leds\.unit' is 'watts'"),
        (lambda d: d["leds"].update(file="../x.csv"), r"field 'leds\.file' '\.\./x\.csv' leaves"),
        (lambda d: d["camera"].update(file="gone.csv"), r"field 'camera\.file': .*gone\.csv is missing"),
        (lambda d: d["leds"].update(names=["a"]), r"field 'leds\.names'"),
        (lambda d: d["dark"].pop("black_level"), r"field 'dark\.black_level' is missing"),
        (lambda d: d["leds"].update(relative_power="high"), r"field 'leds\.relative_power' is 'high'"),
    ],
)
def test_bad_fields_named(tmp_path, change, message):
    edit(tmp_path, change)
    with pytest.raises(CalibrationError, match=message):
        load_calibration(tmp_path)


def test_bad_table_named(tmp_path):
    save_calibration(full_set(), tmp_path)
    (tmp_path / "camera.csv").write_text("wavelength_nm,R,G,B\n400,1,2\n")
    with pytest.raises(CalibrationError, match=r"field 'camera\.file': .*camera\.csv:2: 3 cells"):
        load_calibration(tmp_path)


def test_missing_and_invalid_json(tmp_path):
    with pytest.raises(CalibrationError, match=r"calibration\.json: cannot be read"):
        load_calibration(tmp_path)
    (tmp_path / "calibration.json").write_text("{\n  oops")
    with pytest.raises(CalibrationError, match=r"calibration\.json: line 2 column \d+: .*; expected valid JSON"):
        load_calibration(tmp_path)
