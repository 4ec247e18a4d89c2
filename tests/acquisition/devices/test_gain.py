"""Cameras' gain as they name it (issue 29): ``--gain`` in dB, ``--gain-raw`` in camera units.

The mapping (:mod:`acquisition.devices.aravis.gain`) is tested on its own, then on real Aravis
fakes only — the in-process ``Fake`` interface and the GigE Vision fake opened at 127.0.0.1,
never discovery: Aravis's own fake (``GainRaw`` 0–10, no ``Gain``; the camera of the issue) and
the ``aravis-fake`` rig's camera models (``--fake-camera``: ``gain-raw`` with an unscaled integer
``GainRaw``, ``gain-db`` with ``Gain`` only, ``gain-selector`` with ``AnalogAll``/``DigitalAll``
and ``GainAuto`` on at power-up), end to end through ``msflash capture`` and ``run``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.app.cli_common import dumps_json
from msflash.acquisition.app.run_html import exposure_summary
from msflash.acquisition.devices.aravis.camera_features import FeatureInfo
from msflash.acquisition.devices.aravis.fake_models import FAKE_MODELS
from msflash.acquisition.devices.aravis.gain import (
    GAIN_FEATURES,
    GainControl,
    GainRequest,
    choose_gain_control,
    choose_selector,
    parse_gain_db,
    parse_gain_raw,
)
from msflash.acquisition.devices.aravis.gv_fake import AravisGvFake
from msflash.acquisition.errors import CameraSettingError, RigOpenError, UsageError
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.exposure import ExposurePlan, ExposurePolicy
from msflash.acquisition.session.live import LiveStream
from msflash.acquisition.session.rig import open_aravis_fake_rig
from msflash.acquisition.session.run import LedCapture
from msflash.processing import datasets
from tests.acquisition.support.fake_genicam import use_fake_genicam
from tests.acquisition.support.hw_rig import booth_on_pty

CAMERA = "camera X (serial 1)"

# -- the mapping, without a camera ----------------------------------------------------------------


def test_gain_options_parse_their_units() -> None:
    assert parse_gain_db("6") == parse_gain_db("6dB") == parse_gain_db(" 6 DB ") == GainRequest(6.0, "dB")
    assert parse_gain_raw("136") == GainRequest(136.0, "raw")
    for bad in ("loud", "6x", "nan", "inf", "6 dB extra"):
        with pytest.raises(argparse.ArgumentTypeError, match="expected a gain in dB, e.g. 6 or 6dB"):
            parse_gain_db(bad)
    with pytest.raises(argparse.ArgumentTypeError, match="camera's own gain units"):
        parse_gain_raw("6dB")


def _info(name: str, kind: str, low: float, high: float, unit: str = "", increment: float | None = None) -> FeatureInfo:
    return FeatureInfo(name, kind, "RW", low, low, high, increment, unit)  # type: ignore[arg-type]


def test_a_db_gain_goes_to_a_feature_in_db_and_a_raw_gain_to_gainraw() -> None:
    features = {"Gain": _info("Gain", "float", 0, 24, "dB"), "GainRaw": _info("GainRaw", "integer", 0, 10)}
    assert choose_gain_control(features, GAIN_FEATURES, GainRequest(6, "dB")).feature == "Gain"
    assert choose_gain_control(features, GAIN_FEATURES, GainRequest(6, "raw")).feature == "GainRaw"
    assert choose_gain_control(features, ("GainRaw", "Gain"), None).feature == "Gain"  # no dB scale for GainRaw


def test_an_unscaled_gainraw_refuses_db_and_names_gain_raw_with_its_range() -> None:
    control = choose_gain_control({"GainRaw": _info("GainRaw", "integer", 100, 800)}, GAIN_FEATURES, None)
    assert control.feature == "GainRaw" and not control.db_known
    with pytest.raises(CameraSettingError) as refused:
        control.value_for(GainRequest(6, "dB"), CAMERA)
    assert str(refused.value) == (
        "camera X (serial 1): --gain 6 dB: this camera's gain is GainRaw, a whole number in 100 … 800 "
        "(camera units, no known dB scale: profile 'generic' gives no gain_raw_per_db); expected --gain-raw N "
        "in that range, or gain_raw_per_db in its profile (genicam/profiles.json) to use dB"
    )
    assert control.value_for(GainRequest(200, "raw"), CAMERA) == 200
    with pytest.raises(
        CameraSettingError, match=r"--gain-raw 99: GainRaw cannot be 99; expected a whole number in 100"
    ):
        control.value_for(GainRequest(99, "raw"), CAMERA)
    with pytest.raises(CameraSettingError, match=r"--gain-raw 150.5: GainRaw cannot be 150.5"):
        control.value_for(GainRequest(150.5, "raw"), CAMERA)


def test_a_profiled_gainraw_maps_db_by_its_documented_rule() -> None:
    control = choose_gain_control(
        {"GainRaw": _info("GainRaw", "integer", 0, 1023, increment=1)}, GAIN_FEATURES, None, 28.0, "maker"
    )
    assert control.value_for(GainRequest(6, "dB"), CAMERA) == 168  # round(6 dB × 28 units per dB)
    assert control.db_of(168) == pytest.approx(6.0)
    with pytest.raises(CameraSettingError) as refused:
        control.value_for(GainRequest(40, "dB"), CAMERA)
    assert "GainRaw cannot be 1120 (40 dB at 28 per dB, profile 'maker': gain_raw_per_db 28)" in str(refused.value)
    assert "expected a whole number in 0 … 1023 (camera units; 0 … 36.5357 dB)" in str(refused.value)


def test_a_linear_gain_feature_is_converted_exactly() -> None:
    control = choose_gain_control({"Gain": _info("Gain", "float", 1.0, 16.0, "x")}, GAIN_FEATURES, None)
    assert control.scale == "linear" and control.value_for(GainRequest(6.0206, "dB"), CAMERA) == pytest.approx(2.0)
    with pytest.raises(CameraSettingError, match=r"Gain cannot be 31.62 x \(30 dB\); expected a number in 1 … 16 x"):
        control.value_for(GainRequest(30, "dB"), CAMERA)


def test_the_selector_entry_is_the_users_or_the_whole_analogue_gain() -> None:
    assert choose_selector(("DigitalAll", "AnalogAll"), None) == ("AnalogAll", "")
    assert choose_selector(("All", "AnalogAll"), None) == ("All", "")
    assert choose_selector(("DigitalAll", "AnalogAll"), "DigitalAll") == ("DigitalAll", "")
    assert choose_selector(("Tap1",), None) == ("Tap1", "")
    assert choose_selector(("Red", "Blue"), None)[0] is None
    assert "no entry 'Green'; expected one of Red, Blue" in choose_selector(("Red", "Blue"), "Green")[1]


def test_a_gain_that_cannot_be_set_says_why() -> None:
    stuck = choose_gain_control(
        {"Gain": _info("Gain", "float", 0, 24, "dB")}, GAIN_FEATURES, None, why="GainAuto is Continuous …"
    )
    with pytest.raises(CameraSettingError, match=r"^camera X \(serial 1\): --gain 6 dB: GainAuto is Continuous"):
        stuck.value_for(GainRequest(6, "dB"), CAMERA)
    none = choose_gain_control({}, GAIN_FEATURES, GainRequest(6, "dB"))
    assert none.feature is None and "no gain feature; expected one of Gain, GainAbs, GainRaw" in none.why
    assert GainControl(None, why="x").to_dict()["unit"] is None


# -- the cameras: Aravis's fakes ------------------------------------------------------------------


def test_aravis_own_fake_has_gainraw_only_and_its_profile_maps_db(aravis: ModuleType) -> None:
    use_fake_genicam(None)
    with aravis.AravisCamera("Fake_1", interfaces="fake", pixel_format="Mono8", roi=(0, 0, 64, 48)) as camera:
        assert not camera.has_feature("Gain") and camera.gain_feature == "GainRaw"
        with pytest.raises(CameraSettingError) as refused:
            camera.configure_gain(GainRequest(20, "dB"))
        assert str(refused.value) == (
            "camera Fake (serial 1): --gain 20 dB: GainRaw cannot be 20 (20 dB at 1 per dB, profile 'aravis-fake': "
            "gain_raw_per_db 1); expected a whole number in 0 … 10 (camera units; 0 … 10 dB)"
        )
        camera.configure_gain(GainRequest(6, "dB"))
        assert camera.get_feature("GainRaw") == 6 and camera.gain == pytest.approx(10 ** (6 / 20))
        assert camera.native_gain is not None and camera.native_gain.to_dict() == {
            "feature": "GainRaw",
            "value": 6,
            "unit": "raw",
        }
        with pytest.raises(CameraSettingError, match=r"a gain of 2x on --gain 6 dB is 12.02 dB, GainRaw 12; expected"):
            camera.check_step_gain(2.0)  # a plan step's own gain beyond the range: refused before a write
        assert camera.get_feature("GainRaw") == 6


def test_the_range_is_the_selected_gains(aravis: ModuleType) -> None:
    use_fake_genicam(FAKE_MODELS["gain-selector"].xml_path())
    try:
        camera = aravis.AravisCamera("Fake_1", interfaces="fake", pixel_format="Mono8", roi=(0, 0, 64, 48))
    finally:
        use_fake_genicam(None)
    with camera:
        assert camera.gain_control.selector == "AnalogAll"  # no All: the whole analogue gain
        camera.configure_gain(GainRequest(20, "dB"))
        with pytest.raises(
            CameraSettingError,
            match=r"--gain 20 dB: Gain \(GainSelector DigitalAll\) cannot be 20 dB; expected a number in 0 … 12 dB",
        ):
            camera.configure_gain(GainRequest(20, "dB"), selector="DigitalAll")
        camera.configure_gain(GainRequest(3, "dB"), selector="DigitalAll")
        assert camera.native_gain is not None and camera.native_gain.selector == "DigitalAll"
        camera.set_feature("GainSelector", "AnalogAll")
        assert camera.get_feature("Gain") == pytest.approx(20.0)  # each entry keeps its own gain


# -- the camera: Aravis's own GigE fake on 127.0.0.1, through `msflash capture` -----------


def _capture_on_gige_fake(tmp_path: Path, led_spectra_csv: Path, port: str, *options: str) -> tuple[int, Path]:
    out = tmp_path / f"c{len(list(tmp_path.iterdir()))}"
    status = main(
        [
            "capture",
            "--camera",
            "127.0.0.1",
            "--interfaces",
            "gige",
            "--port",
            port,
            "--led-spectra",
            str(led_spectra_csv),
            "--exposure",
            "10000",
            "--roi",
            "0,0,64,48",  # small frames: the fake's 512 × 512 ones time out on a loaded machine
            *options,
            "--out",
            str(out),
        ]
    )
    return status, out


def test_gain_on_the_gainraw_gige_fake_is_checked_before_the_sequence_and_recorded(
    aravis: ModuleType, tmp_path: Path, led_spectra_csv: Path, capsys: pytest.CaptureFixture
) -> None:
    leds = datasets.load_spectra_csv(led_spectra_csv, kind="spd", unit="energy")
    with (
        booth_on_pty(leds) as port,
        AravisGvFake(serial="ISSUE29", genicam_xml=None),
    ):  # Aravis's own XML: GainRaw 0-10
        capsys.readouterr()
        status, out = _capture_on_gige_fake(tmp_path, led_spectra_csv, port, "--gain", "20")
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 2 and len(err) == 1, err
        assert err[0] == (
            "msflash: error: camera Fake (serial ISSUE29): --gain 20 dB: GainRaw cannot be 20 (20 dB at 1 per dB, "
            "profile 'aravis-fake': gain_raw_per_db 1); expected a whole number in 0 … 10 (camera units; 0 … 10 dB)"
        )
        assert not (out / "sequence").exists()  # refused before the sequence began
        status, out = _capture_on_gige_fake(tmp_path, led_spectra_csv, port, "--gain", "6")
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 0, err
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    assert sequence.camera.extra["camera_options"]["read_back"] == {
        "gain": {"feature": "GainRaw", "value": 6, "unit": "raw"},
        "roi": [0, 0, 64, 48],
    }
    assert [frame.extra["camera_gain"] for frame in sequence.frames] == [
        {"feature": "GainRaw", "value": 6, "unit": "raw"}
    ] * len(sequence.frames)
    assert all(frame.gain == pytest.approx(10 ** (6 / 20)) for frame in sequence.frames)
    assert sequence.camera.extra["gain"]["scale"] == "profile 'aravis-fake': gain_raw_per_db 1"
    # The fake's test patterns carry no LED signal: a warning naming each LED, never a figure (inf, nan).
    snr = next(line for line in err if line.startswith("msflash: LED SNR"))
    assert snr.endswith(
        "led440 no signal, led478 no signal, led500 no signal, led522 no signal, "
        "led597 no signal, led636 no signal, led661 no signal"
    )
    assert sum(line.startswith("msflash: warning: LED led") and "no LED signal" in line for line in err) == 7


# -- the aravis-fake rig's camera models, end to end ----------------------------------------------


def _capture(out: Path, *options: str) -> int:
    return main(["capture", "--rig", "aravis-fake", "--exposure", "4000", *options, "--out", str(out)])


def test_gain_raw_camera_refuses_db_and_takes_its_own_units(
    aravis: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    for options, expected in (
        (("--gain", "6"), "--gain 6 dB: this camera's gain is GainRaw, a whole number in 100 … 800"),
        (("--gain-raw", "900"), "--gain-raw 900: GainRaw cannot be 900; expected a whole number in 100 … 800"),
    ):
        assert _capture(tmp_path / "refused", "--fake-camera", "gain-raw", *options) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("msflash: error: camera Fake-GainRaw (serial MSFRIG01): ")
        assert expected in err[0]
        assert not (tmp_path / "refused" / "sequence").exists()
    means = {}
    for raw in ("100", "200"):
        out = tmp_path / f"raw{raw}"
        assert _capture(out, "--fake-camera", "gain-raw", "--gain-raw", raw) == 0
        sequence = read_sequence(out / "sequence")
        gain = sequence.camera.extra["gain"]
        assert (gain["feature"], gain["unit"], gain["range"], gain["db_per_unit"]) == (
            "GainRaw",
            "raw",
            [100, 800],
            None,
        )
        assert gain["linear"].startswith(f"relative: frames[].gain is 1 at GainRaw {raw}")
        assert all(frame.gain == 1.0 for frame in sequence.frames)  # the same unknown gain on every frame
        assert all(
            frame.extra["camera_gain"] == {"feature": "GainRaw", "value": int(raw), "unit": "raw"}
            for frame in sequence.frames
        )
        means[raw] = float(np.mean(sequence.load_frame(0).astype(float) - sequence.camera.black_level))
    # The twin's sensor applies its true gain (GainRaw 200 is ×2): the frames show what was set.
    assert means["200"] / means["100"] == pytest.approx(2.0, rel=0.05)


def test_gain_db_camera_records_its_gain_in_db(aravis: ModuleType, tmp_path: Path) -> None:
    out = tmp_path / "db"
    assert _capture(out, "--fake-camera", "gain-db", "--gain", "6dB") == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.camera.model == "Fake-GainDB"
    gain = sequence.camera.extra["gain"]
    assert (gain["feature"], gain["selector"], gain["unit"], gain["requested"]) == (
        "Gain",
        None,
        "dB",
        {"value": 6.0, "unit": "dB"},
    )
    assert all(20 * math.log10(frame.gain) == pytest.approx(6.0, abs=0.02) for frame in sequence.frames)
    assert all(frame.extra["camera_gain"]["unit"] == "dB" for frame in sequence.frames)


def test_gain_selector_camera_runs_with_its_analogue_gain_and_auto_gain_off(
    aravis: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "run"
    assert (
        main(["run", "--rig", "aravis-fake", "--fake-camera", "gain-selector", "--gain", "6", "--out", str(out)]) == 0
    )
    sequence = read_sequence(out / "sequence")
    gain = sequence.camera.extra["gain"]
    assert (gain["feature"], gain["selector"], gain["range"]) == ("Gain", "AnalogAll", [0.0, 24.0])
    assert all(frame.extra["camera_gain"]["selector"] == "AnalogAll" for frame in sequence.frames)
    summary = json.loads((out / "run.json").read_text())
    # GainAuto was on at power-up: had it stayed on, the twin's auto gain would have changed the frames.
    assert summary["spectrum_rmse_vs_truth"] <= 1.3 * summary["spectrum_rmse_led_bound"]


def test_gain_selector_camera_power_up_state_is_undone_before_any_frame(
    aravis: ModuleType, caplog: pytest.LogCaptureFixture
) -> None:
    model = FAKE_MODELS["gain-selector"]
    with open_aravis_fake_rig(fake_camera="gain-selector") as rig:
        camera = rig.camera.aravis
        assert camera.get_feature("GainAuto") == "Off"
        assert rig.camera_extra["gain"]["selector"] == "AnalogAll"
        fake = rig.camera._fake
        assert model.true_gain(fake.read_register) == pytest.approx(10 ** (2 / 20))  # DigitalAll's 2 dB stays
        # … and is said: recorded, and warned once.
        assert rig.camera_extra["gain"]["other_selectors"] == {"DigitalAll": pytest.approx(2.0)}
    warned = [r.getMessage() for r in caplog.records if "GainSelector DigitalAll" in r.getMessage()]
    assert warned == [
        "camera Fake-GainSelector (serial MSFRIG01): GainSelector DigitalAll: Gain is 2 dB, left as the camera "
        "has it (msflash sets AnalogAll); frames record the AnalogAll gain only"
    ]


def test_live_gain_is_checked_against_the_camera(aravis: ModuleType) -> None:
    with open_aravis_fake_rig(fake_camera="gain-raw") as rig:
        stream = LiveStream(rig)
        with pytest.raises(UsageError, match=r"gain 2: camera Fake-GainRaw \(serial MSFRIG01\): a gain of 2x"):
            stream.set_exposure(5000.0, 2.0)
        assert stream.set_exposure(5000.0, 1.0).gain == 1.0
    with open_aravis_fake_rig(fake_camera="gain-db") as rig:
        stream = LiveStream(rig)
        stream.set_exposure(5000.0, 10.0)
        with pytest.raises(UsageError, match=r"a gain of 32x is 30.1 dB, Gain 30.103; expected a number in 0 … 24 dB"):
            stream.set_exposure(5000.0, 32.0)


# -- the rig's own fake, not another program's ----------------------------------------------------


def test_a_fake_of_another_program_on_the_port_is_refused(
    aravis: ModuleType, gv_fake_process: Any, capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    gv_fake_process(serial="OTHER01")
    assert main(["capture", "--rig", "aravis-fake", "--exposure", "4000", "--out", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "GigE Vision fake MSFRIG01: 127.0.0.1:3956 is already bound by another program" in err[0]


def test_the_rig_checks_the_serial_and_model_it_opened(
    aravis: ModuleType, gv_fake_process: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The port probe is the first guard; with it blinded (the one stand-in here: a probe that sees
    # nothing), the rig's own fake starts beside the other program's, Aravis reaches the other one
    # (the kernel hands the port's datagrams to the first socket bound), and the identity check stops it.
    gv_fake_process(serial="OTHER02")
    from msflash.acquisition.devices.aravis import gv_fake

    monkeypatch.setattr(gv_fake, "gvcp_port_holder", lambda *_args: None)
    with pytest.raises(RigOpenError) as refused:
        open_aravis_fake_rig()
    assert "the camera at 127.0.0.1 is Aravis Fake serial OTHER02, not this rig's fake (Fake serial MSFRIG01)" in str(
        refused.value
    )


# -- no LED signal: a warning naming the LED, never a number --------------------------------------


def test_led_snr_without_signal_is_a_warning_and_null_in_json() -> None:
    from msflash.acquisition.session.led_snr import led_snr_warnings

    names = ["led440", "led480", "led500", "led520"]
    snr = [12.5, math.inf, -4e14, math.nan]
    captured = LedCapture(
        ExposurePlan(
            1000.0, (1000.0,) * 4, (5.0, math.nan, math.inf, -4e14), "difference image", (1.0, 1e6), ExposurePolicy()
        ),
        [],
        [],
        0.0,
        snr,
        "difference image",
        tuple(led_snr_warnings(names, snr, "measured SNR")),
    )
    summary = exposure_summary(captured.plan, 1000.0, captured)
    text = dumps_json(summary)
    parsed = json.loads(text, parse_constant=lambda token: pytest.fail(f"{token} in JSON"))
    assert parsed["led_snr"] == [12.5, None, None, None]
    assert parsed["predicted_led_snr"] == [5.0, None, None, None]
    assert "4e+14" not in text
    warnings = parsed["led_snr_warnings"]
    assert [w.split(":")[0] for w in warnings] == ["LED led480", "LED led500", "LED led520"]
    assert "no brighter than the ambient frame" in warnings[1] and "no noise" in warnings[0]
