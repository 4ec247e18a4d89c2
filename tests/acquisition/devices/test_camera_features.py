"""Camera options (``acquisition.devices.aravis.camera_features``) on the Aravis in-process fake camera.

Only the ``Fake`` interface is enabled, so nothing is broadcast. The fake is loaded with msflash's
SFNC XML (``sfnc_fake_camera``), which has the trigger, line, gain and black-level features real
cameras name the SFNC way; binning, ROI and pixel formats are the fake's own.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.devices.aravis.camera_features import (
    CameraOptions,
    apply_camera_options,
    apply_feature,
    configure_camera,
    options_from_json,
    parse_binning,
    parse_feature,
    parse_roi,
)
from msflash.acquisition.devices.aravis.discovery import FAKE_SFNC_XML
from msflash.acquisition.devices.aravis.profiles import CameraProfile, load_profiles
from msflash.acquisition.errors import CameraSettingError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.processing import datasets
from tests.acquisition.support.fake_genicam import use_fake_genicam
from tests.acquisition.support.hw_rig import booth_on_pty, fake_camera_capture

pytestmark = pytest.mark.aravis


# -- parsing (no camera) -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("parse", "text"),
    [
        (parse_roi, "0,0,640"),
        (parse_roi, "a,b,c,d"),
        (parse_roi, "-1,0,8,8"),
        (parse_roi, "0,0,0,8"),
        (parse_binning, "0"),
        (parse_binning, "2x2x2"),
        (parse_binning, "two"),
        (parse_feature, "Gain"),
        (parse_feature, "=3"),
        (parse_feature, "Ga in=3"),
    ],
)
def test_malformed_option_values_are_refused_with_an_example(parse: Any, text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=rf"'{text}': expected .*e\.g\."):
        parse(text)


def test_profile_options_from_json_and_their_errors() -> None:
    options = options_from_json(
        {
            "trigger_line": "Line2",
            "gain_db": 3,
            "roi": [0, 0, 64, 48],
            "binning": 2,
            "features": {"BlackLevel": 16, "LineInverter": True},
        },
        where="p.json profile 'x'",
    )
    assert options == CameraOptions(
        trigger_line="Line2",
        gain_db=3.0,
        roi=(0, 0, 64, 48),
        binning=(2, 2),
        features=(("BlackLevel", "16"), ("LineInverter", "true")),
    )
    assert options_from_json(options.to_dict(), where="again") == options
    with pytest.raises(
        CameraSettingError,
        match=r"p\.json profile 'x': options has unknown key 'gian_db'; expected "
        r"some of trigger_line",
    ):
        options_from_json({"gian_db": 3}, where="p.json profile 'x'")
    with pytest.raises(CameraSettingError, match=r"w: options\.roi '1,2': expected X,Y,W,H"):
        options_from_json({"roi": [1, 2]}, where="w")
    with pytest.raises(CameraSettingError, match=r"w: options\.gain_db is 'loud'; expected a number of dB"):
        options_from_json({"gain_db": "loud"}, where="w")


# -- on the fake camera ------------------------------------------------------------------------


def test_binning_roi_and_features_are_applied_and_read_back(sfnc_fake_camera: Any) -> None:
    camera = sfnc_fake_camera
    applied = apply_camera_options(
        camera,
        CameraOptions(
            binning=(2, 2),
            roi=(8, 4, 64, 48),
            features=(
                ("BlackLevel", "64"),
                ("TriggerActivation", "FallingEdge"),
                ("LineInverter", "true"),
                ("TriggerDelay", "12.5"),
            ),
        ),
    )
    assert applied.binning == (2, 2) and applied.roi == (8, 4, 64, 48)
    # The fake's TriggerDelay register holds whole microseconds: what it reads back is what is kept.
    assert applied.features == {
        "BlackLevel": 64,
        "TriggerActivation": "FallingEdge",
        "LineInverter": True,
        "TriggerDelay": 12.0,
    }
    assert camera.get_feature("BinningHorizontal") == 2 and camera.roi == (8, 4, 64, 48)
    assert camera.get_feature("BlackLevel") == 64 and camera.info.black_level == 64
    assert [apply_feature(camera, "BlackLevel", text) for text in ("0x20", "016", "7")] == [32, 16, 7]


@pytest.mark.parametrize(
    ("feature", "value", "message"),
    [
        (
            "TriggerActivation",
            "Sideways",
            r"--feature TriggerActivation=Sideways: TriggerActivation cannot be 'Sideways' "
            r"\(now RisingEdge\); expected one of RisingEdge, FallingEdge, AnyEdge",
        ),
        ("Gain", "99", r"Gain cannot be '99' \(now 0\); expected a number in 0 … 24 dB"),
        ("BlackLevel", "5000", r"BlackLevel cannot be '5000' \(now 0\); expected a whole number in 0 … 4095"),
        ("BlackLevel", "dark", r"BlackLevel cannot be 'dark'.*expected a whole number in 0 … 4095"),
        ("LineInverter", "maybe", r"LineInverter cannot be 'maybe'.*expected true or false"),
        ("SensorWidth", "8", r"SensorWidth is integer, access RO; expected a writable feature"),
        ("TriggerSoftware", "1", r"TriggerSoftware is command, access WO; expected a writable feature"),
        (
            "Bogus",
            "1",
            r"--feature Bogus=1: no feature Bogus; expected one the camera offers — `msflash devices "
            r"--features ID` lists them",
        ),
    ],
)
def test_a_value_the_camera_cannot_take_names_the_feature_and_what_it_allows(
    sfnc_fake_camera: Any, feature: str, value: str, message: str
) -> None:
    with pytest.raises(CameraSettingError, match=r"^camera Fake \(serial 1\): .*" + message):
        apply_feature(sfnc_fake_camera, feature, value)


def test_lines_and_gain_are_checked_before_any_capture(sfnc_fake_camera: Any) -> None:
    with pytest.raises(
        CameraSettingError,
        match=r"--trigger-line Line7: TriggerSource has no entry 'Line7'; "
        r"expected one of Line0, Software, Line1, Line2",
    ):
        apply_camera_options(sfnc_fake_camera, CameraOptions(trigger_line="Line7"))
    with pytest.raises(
        CameraSettingError,
        match=r"--strobe-line Out3: LineSelector has no entry 'Out3'; "
        r"expected one of Line0, Line1, Line2",
    ):
        apply_camera_options(sfnc_fake_camera, CameraOptions(strobe_line="Out3"))
    with pytest.raises(
        CameraSettingError,
        match=r"--gain 30 dB: Gain \(GainSelector All\) cannot be 30 dB; expected a number in 0 … 24 dB",
    ):
        apply_camera_options(sfnc_fake_camera, CameraOptions(gain_db=30.0))


def test_an_roi_outside_the_sensor_names_the_limits(sfnc_fake_camera: Any) -> None:
    with pytest.raises(
        CameraSettingError,
        match=r"--roi 0,0,4096,64: the camera refused it .*expected OffsetX "
        r"0 … 2048; OffsetY 0 … 2048; Width 1 … 2048; Height 1 … 2048",
    ):
        apply_camera_options(sfnc_fake_camera, CameraOptions(roi=(0, 0, 4096, 64)))


def test_trigger_and_strobe_lines_and_gain_reach_the_camera_when_a_plan_is_prepared(sfnc_fake_camera: Any) -> None:
    camera = sfnc_fake_camera
    configure_camera(camera, CameraOptions(trigger_line="Line2", strobe_line="Line2", gain_db=6.0), strobe=True)
    camera.prepare(CapturePlan.ambient_then_each_led(2, 1000.0, gain=2.0, trigger="booth"))
    assert camera.get_feature("TriggerSource") == "Line2" and camera.get_feature("TriggerMode") == "On"
    assert camera.get_feature("LineSelector") == "Line2" and camera.get_feature("LineSource") == "ExposureActive"
    assert camera.gain_db == pytest.approx(6.0 + 20 * 0.30103, abs=1e-3)  # --gain times the step's own gain 2
    camera.stop()


def test_command_line_options_override_the_profiles(tmp_path: Path, aravis: ModuleType, sfnc_fake_camera: Any) -> None:
    profiles = tmp_path / "profiles.json"
    profiles.write_text(
        json.dumps(
            {
                "profiles": [
                    {
                        "name": "bench",
                        "vendor": ".*",
                        "model": ".*",
                        "options": {
                            "trigger_line": "Line1",
                            "binning": [2, 1],
                            "features": {"BlackLevel": 32, "LineInverter": True},
                        },
                    }
                ]
            }
        )
    )
    ((_, _, profile),) = load_profiles(profiles)
    setup = configure_camera(
        sfnc_fake_camera, CameraOptions(features=(("BlackLevel", "8"),)), strobe=False, profile_options=profile.options
    )
    assert setup.options.trigger_line == "Line1" and setup.options.binning == (2, 1)
    assert setup.applied.features == {"BlackLevel": 8, "LineInverter": True}
    assert (
        sfnc_fake_camera.get_feature("BinningHorizontal") == 2 and sfnc_fake_camera.get_feature("BinningVertical") == 1
    )
    assert setup.to_dict()["read_back"]["features"]["BlackLevel"] == 8


def test_a_profile_with_a_bad_option_names_file_and_profile(tmp_path: Path, aravis: ModuleType) -> None:
    profiles = tmp_path / "profiles.json"
    profiles.write_text(
        json.dumps({"profiles": [{"name": "bad", "vendor": ".*", "model": ".*", "options": {"binning": "0"}}]})
    )
    with pytest.raises(CameraSettingError, match=rf"{profiles} profile 'bad': options.binning '0': expected"):
        load_profiles(profiles)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('{"profiles": [\n  {"name": "a", "vendor": ".*",\n   "model": ".*",}\n]}', r"line 3 column 18"),
        ('{"profiles": [{"name": "a", "vendor": ".*", "model": ".*", "read_noise_e": NaN}]}', "is NaN"),
        ('{"profiles": [{"name": "a", "vendor": ".*", "model": ".*", "name": "b"}]}', "appears twice"),
        ('{"profile": []}', "field 'profiles' is missing"),
        (
            '{"profiles": [{"name": "a", "vendor": ".*", "model": ".*", "gain_raw_per_db": "8"}]}',
            r"profiles\[0\]\.gain_raw_per_db is '8'",
        ),
        (
            '{"profiles": [{"name": "a", "vendor": ".*", "model": ".*", "exposure": 1}]}',
            r"profiles\[0\]\.exposure is unknown",
        ),
        ('{"profiles": [{"name": "a", "model": ".*"}]}', r"profiles\[0\]\.vendor is missing"),
        ('{"profiles": [{"name": "a", "vendor": ".*", "model": ".*", "gain_features": "Gain"}]}', "expected a list"),
    ],
)
def test_a_broken_profiles_file_is_one_line_naming_file_and_field(
    tmp_path: Path, aravis: ModuleType, text: str, expected: str
) -> None:
    profiles = tmp_path / "profiles.json"
    profiles.write_text(text)
    with pytest.raises(CameraSettingError, match=expected) as caught:
        load_profiles(profiles)
    message = str(caught.value)
    assert message.startswith(f"{profiles}:") and "\n" not in message


def test_the_shipped_profiles_read_as_data(aravis: ModuleType) -> None:
    profiles = load_profiles()
    assert profiles and all(isinstance(profile, CameraProfile) for _, _, profile in profiles)


# -- the command line ------------------------------------------------------------------------------


@pytest.fixture
def sfnc_fake_xml(aravis: ModuleType) -> Iterator[None]:
    """The in-process fake built with msflash's SFNC XML while the test runs."""
    use_fake_genicam(FAKE_SFNC_XML)
    try:
        yield
    finally:
        use_fake_genicam(None)


def test_devices_features_lists_type_value_and_range(sfnc_fake_xml: None, capsys: pytest.CaptureFixture) -> None:
    assert main(["devices", "--interfaces", "fake", "--features", "Fake_1", "--json"]) == 0
    features = {f["name"]: f for f in json.loads(capsys.readouterr().out)["features"]}
    assert features["Gain"] == {
        "name": "Gain",
        "type": "float",
        "access": "RW",
        "value": 0.0,
        "minimum": 0.0,
        "maximum": 24.0,
        "increment": None,
        "unit": "dB",
        "category": "MsflashSfnc",
        "under_root": True,
        "visibility": "Beginner",
        "msflash": "writes",
    }
    assert features["TriggerSource"]["entries"] == ["Line0", "Software", "Line1", "Line2"]
    assert "Mono12p" in features["PixelFormat"]["entries"]
    assert features["LineStatus"]["access"] == "RO" and features["LineStatus"]["type"] == "boolean"
    assert "msflash" not in features["LineStatus"]  # msflash never reads it
    assert main(["devices", "--interfaces", "fake", "--features", "Fake_1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("# camera Fake (serial 1): ")
    assert "BlackLevel\tinteger\tRW\t0\ta whole number in 0 … 4095\tmsflash writes" in lines


def test_devices_features_lists_what_msflash_uses_outside_root(
    capsys: pytest.CaptureFixture, aravis: ModuleType
) -> None:
    # Aravis's own fake keeps GainRaw and GainAuto in a category Root does not list: a walk of Root
    # alone hid the one gain feature the camera has (issue 29).
    use_fake_genicam(None)
    assert main(["devices", "--interfaces", "fake", "--features", "Fake_1", "--json"]) == 0
    listing = json.loads(capsys.readouterr().out)
    features = {f["name"]: f for f in listing["features"]}
    assert features["GainRaw"] == {
        "name": "GainRaw",
        "type": "integer",
        "access": "RW",
        "value": 0,
        "minimum": 0,
        "maximum": 10,
        "increment": 1,
        "unit": "",
        "under_root": False,
        "visibility": "Beginner",
        "msflash": "writes",
    }
    assert features["GainAuto"]["under_root"] is False and features["GainAuto"]["entries"] == [
        "Off",
        "Once",
        "Continuous",
    ]
    assert listing["gain"]["feature"] == "GainRaw" and listing["gain"]["range"] == [0, 10]
    assert main(["devices", "--interfaces", "fake", "--features", "Fake_1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    hidden = lines.index("# not under the camera's Root category, but read or written by msflash:")
    assert "GainRaw\tinteger\tRW\t0\ta whole number in 0 … 10\tmsflash writes" in lines[hidden:]
    assert lines[-1] == (
        "# --gain/--gain-raw: GainRaw, 0 … 10 raw (profile 'aravis-fake': gain_raw_per_db 1): "
        "--gain in dB or --gain-raw in these units"
    )


def test_devices_features_of_a_missing_camera_is_one_line(capsys: pytest.CaptureFixture, aravis: ModuleType) -> None:
    assert main(["devices", "--interfaces", "fake", "--features", "SN404"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("msflash: error: camera 'SN404': not found on fake (found: Fake_1")


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (
            ["--feature", "TriggerActivation=Sideways"],
            "TriggerActivation cannot be 'Sideways' (now RisingEdge); "
            "expected one of RisingEdge, FallingEdge, AnyEdge, LevelHigh, LevelLow",
        ),
        (["--gain", "40"], "--gain 40 dB: Gain (GainSelector All) cannot be 40 dB; expected a number in 0 … 24 dB"),
        (
            ["--gain-raw", "11"],
            "--gain-raw 11: GainRaw (GainSelector All) cannot be 11; expected a whole number in 0 … 10",
        ),
        (["--trigger-line", "Line9"], "--trigger-line Line9: TriggerSource has no entry 'Line9'"),
        (
            ["--binning", "32"],
            "--binning 32x32: BinningHorizontal cannot be '32' (now 1); expected a whole number in 1 … 16",
        ),
    ],
)
def test_cli_camera_option_errors_exit_2_with_one_line(
    sfnc_fake_xml: None,
    tmp_path: Path,
    led_spectra_csv: Path,
    option: list[str],
    message: str,
    capsys: pytest.CaptureFixture,
) -> None:
    # No booth is needed: the camera's options are refused before the booth is opened (/dev/null: a device, no booth).
    status = main(
        fake_camera_capture("/dev/null", "--led-spectra", str(led_spectra_csv), *option, "--out", str(tmp_path / "x"))
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith("msflash: error: camera Fake (serial 1): ") and message in err[0]


def test_camera_options_need_the_hardware_rig(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["capture", "--rig", "sim", "--roi", "0,0,64,48", "--out", str(tmp_path / "x")]) == 2
    assert "--roi: describes a hardware rig's camera" in capsys.readouterr().err


def test_cli_capture_applies_the_options_and_records_them(
    sfnc_fake_xml: None, tmp_path: Path, led_spectra_csv: Path
) -> None:
    leds = datasets.load_spectra_csv(led_spectra_csv, kind="spd", unit="energy")
    out = tmp_path / "c"
    with booth_on_pty(leds) as port:
        status = main(
            fake_camera_capture(
                port,
                "--led-spectra",
                str(led_spectra_csv),
                "--exposure",
                "10000",
                "--binning",
                "2",
                "--roi",
                "0,0,64,48",
                "--gain",
                "6",
                "--feature",
                "BlackLevel=16",
                "--feature",
                "TriggerActivation=FallingEdge",
                "--out",
                str(out),
            )
        )
    assert status == 0
    sequence = read_sequence(out / "sequence")
    assert sequence.complete and sequence.load_frame(0).shape[:2] == (48, 64)
    assert sequence.camera.black_level == 16
    # Each frame records the gain the camera read back: 6 dB as the fake's Gain register quantises it.
    gains_db = [20 * math.log10(frame.gain) for frame in sequence.frames]
    assert gains_db == pytest.approx([6.0] * len(sequence.frames), abs=0.02)
    recorded = sequence.camera.extra["camera_options"]
    assert recorded["requested"] == {
        "gain_db": 6.0,
        "roi": [0, 0, 64, 48],
        "binning": [2, 2],
        "features": {"BlackLevel": "16", "TriggerActivation": "FallingEdge"},
    }
    assert recorded["read_back"] == {
        "gain": {"feature": "Gain", "selector": "All", "unit": "dB", "value": pytest.approx(6.0, abs=0.02)},
        "roi": [0, 0, 64, 48],
        "binning": [2, 2],
        "features": {"BlackLevel": 16, "TriggerActivation": "FallingEdge"},
    }
    # With its units: the feature behind each frame's gain, and how --gain was mapped.
    assert all(frame.extra["camera_gain"]["feature"] == "Gain" for frame in sequence.frames)
    gain = sequence.camera.extra["gain"]
    assert (gain["feature"], gain["unit"], gain["range"], gain["requested"]) == (
        "Gain",
        "dB",
        [0.0, 24.0],
        {"value": 6.0, "unit": "dB"},
    )


def test_a_pixel_format_the_camera_does_not_offer_is_bad_input(
    sfnc_fake_xml: None, tmp_path: Path, led_spectra_csv: Path, capsys: pytest.CaptureFixture
) -> None:
    status = main(
        fake_camera_capture(
            "/dev/null",
            "--led-spectra",
            str(led_spectra_csv),
            "--pixel-format",
            "BayerGR12Packed",
            "--out",
            str(tmp_path / "x"),
        )
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1
    assert "PixelFormat 'BayerGR12Packed' is not offered by this camera; expected one of BayerBG8" in err[0]
    assert "Mono12p, Mono12Packed, BayerRG12p, Mono10p" in err[0]
