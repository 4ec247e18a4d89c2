"""msflash evaluate: ΔE00 against the chart under D65 and noise for a chart sequence, and the HTML report."""

from __future__ import annotations

import argparse
import json
import struct
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from msflash.acquisition.app import cli_evaluate
from msflash.acquisition.app.cli import main as msflash_main
from msflash.acquisition.app.cli_common import UsageError
from msflash.acquisition.app.html_report import PNG_SIGNATURE, HtmlReport
from msflash.acquisition.sequence.image_files import read_image, read_image_header
from tests.acquisition.support.png_files import png_chunks
from tests.acquisition.support.report_pages import parse_report


def parser() -> argparse.ArgumentParser:
    root = argparse.ArgumentParser(prog="msflash")
    cli_evaluate.register(root.add_subparsers(dest="command"))
    return root


def run_cli(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    return int(args.handler(args))


@pytest.fixture(scope="module")
def macbeth_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("run") / "tungsten"
    assert msflash_main(["run", "--rig", "sim", "--scene", "macbeth", "--ambient", "tungsten", "--out", str(out)]) == 0
    return out


class TestEvaluateSequence:
    def test_json_files_and_report(self, macbeth_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
        out = tmp_path / "evaluation"
        assert (
            run_cli(["evaluate", str(macbeth_run / "sequence"), "--chart", "macbeth", "--out", str(out), "--json"]) == 0
        )
        result = json.loads(capsys.readouterr().out)
        delta_e = result["delta_e"]
        assert set(delta_e) == {"ambient", "matching", "complementary", "complementary-capture", "ambient-von-kries"}
        assert delta_e["complementary"]["mean"] <= 0.7 * delta_e["ambient"]["mean"]
        assert abs(delta_e["matching"]["mean"] - delta_e["ambient"]["mean"]) <= 1.0
        assert len(delta_e["ambient"]["per_patch"]) == 24
        assert result["layout_uniformity"] < 0.1 and result["noise_flash_image"] == "complementary-capture"

        report = parse_report(out / "report.html")
        assert len(report.embedded) >= 6 and all(image.startswith(PNG_SIGNATURE) for image in report.embedded)
        rows = report.tables["delta-e"]
        assert rows[0] == ["image", "mean ΔE00", "max ΔE00"]
        shown = {row[0]: float(row[1]) for row in rows[1:]}
        assert shown.keys() == delta_e.keys()
        for name, value in shown.items():
            assert value == pytest.approx(delta_e[name]["mean"], abs=0.006)
        assert [row[0] for row in report.tables["noise"][1:]] == ["ambient, von Kries balanced", "complementary flash"]

        saved = json.loads((out / "evaluation.json").read_text())
        assert saved["delta_e"]["ambient"]["mean"] == pytest.approx(delta_e["ambient"]["mean"])
        header = read_image_header(out / "complementary.exr")
        assert header.attributes["msflash:image"] == "complementary"
        assert header.attributes["msflash:flash_weights"] == pytest.approx(result["flash_weights"]["complementary"])
        assert "per µs" in header.attributes["msflash:units"]
        assert header.attributes["msflash:led_names"].count(", ") == 6  # the 7 LEDs named
        exr = oiio.ImageInput.open(str(out / "complementary.exr"))
        try:
            assert len(exr.spec().getattribute("chromaticities")) == 8  # xy of the camera's R, G, B and white
        finally:
            exr.close()
        assert read_image(out / "ambient.tiff").dtype == np.uint16
        assert (out / "ambient.png").read_bytes().startswith(PNG_SIGNATURE)
        # The previews people look at: ≥ 1024 pixels on the long side (the 62×46-pixel chart image enlarged by
        # whole pixels, not stretched by the browser), declared sRGB.
        chunks = png_chunks((out / "ambient.png").read_bytes())
        width, height = struct.unpack(">2I", chunks["IHDR"][:8])
        tiff_height, tiff_width = read_image(out / "ambient.tiff").shape[:2]
        factor = width // tiff_width
        assert (width, height) == (tiff_width * factor, tiff_height * factor) and max(width, height) >= 1024
        assert chunks["sRGB"] == b"\x00"

    def test_a_run_directory_is_accepted_and_output_defaults_beside_the_sequence(
        self, macbeth_run: Path, capsys: pytest.CaptureFixture
    ) -> None:
        assert run_cli(["evaluate", str(macbeth_run), "--chart", "macbeth"]) == 0
        assert capsys.readouterr().out.strip() == str((macbeth_run / "evaluation").resolve())
        assert (macbeth_run / "evaluation" / "report.html").exists()

    @pytest.mark.parametrize(
        ("options", "message"),
        [
            (["--patch-px", "10"], "--patch-px 10 --border-px 2: the macbeth chart is 50×74 pixels"),
            (["--patch-px", "7", "--border-px", "2"], "patches are not uniform"),
            (["--patch-px", "5"], r"patch \d+ is not uniform .* expected every patch inside one chart patch"),
            (["--patch-px", "4", "--border-px", "1"], r"2\d of 24 patches read the same colour as another patch"),
            (["--margin-px", "4"], "--margin-px 4 leaves nothing"),
        ],
    )
    def test_a_wrong_layout_is_refused(
        self, macbeth_run: Path, tmp_path: Path, options: list[str], message: str
    ) -> None:
        with pytest.raises(UsageError, match=message):
            run_cli(["evaluate", str(macbeth_run), "--chart", "macbeth", "--out", str(tmp_path), *options])

    def test_an_unknown_chart_is_a_usage_error(
        self, macbeth_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
    ) -> None:
        with pytest.raises(SystemExit) as exit_info:
            run_cli(["evaluate", str(macbeth_run), "--chart", "esser"])
        assert exit_info.value.code == 2


class TestHtmlReport:
    def test_escapes_text_and_rejects_non_png(self) -> None:
        report = HtmlReport("a <b> & c")
        report.add_paragraph("<script>alert(1)</script>")
        text = report.to_html()
        assert "<script>" not in text and "a &lt;b&gt; &amp; c" in text
        with pytest.raises(ValueError, match="not a PNG"):
            report.add_images([("x", b"GIF89a")])


@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "{seq}", "--chart", "macbeth"],
        ["colour-study", "--ambients", "tungsten"],
        ["local-study", "--uniform", "1", "--mixed", "1", "--no-timing"],
        ["study", "table1"],
    ],
    ids=["evaluate", "colour-study", "local-study", "study"],
)
def test_out_under_a_file_is_refused_before_any_work(capsys, tmp_path: Path, argv: list[str]) -> None:
    """--out below a regular file: evaluate and colour-study ended in a NotADirectoryError/FileExistsError
    traceback, local-study too after running its whole study (20 s for two scenes); study was already right."""
    from tests.helpers import write_test_sequence

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    sequence = write_test_sequence(tmp_path / "seq") if "{seq}" in argv else None
    argv = [str(sequence) if item == "{seq}" else item for item in argv]
    out = blocker / "results"
    assert msflash_main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        err[-1]
        == f"msflash: error: --out {out}: {blocker} is a file; expected a folder (or a path where one can be made)"
    )
    assert not any("Traceback" in line for line in err)


def test_a_blank_ambient_frame_is_named_as_blank_not_as_an_infinite_spread() -> None:
    """Every patch reads the same (an all-black frame): the layout check says the frame is blank."""
    from msflash.acquisition.session.chart_layout import chart_layout, check_layout

    image = np.zeros((120, 160, 3), dtype=np.uint16)
    layout = chart_layout(image.shape[:2], "macbeth", 8, 2, 1)
    with pytest.raises(UsageError, match=r"every patch reads the same value \(0\).*the ambient frame is blank"):
        check_layout(image, layout, None)
