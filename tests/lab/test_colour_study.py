"""msflash colour-study: Fig. 9 ΔE00 and Fig. 3 noise on simulated charts (msflash.lab.colour_study).

Acceptance numbers of the issue, measured on small simulations (Macbeth, 10-pixel patches,
NikonD100, the paper's 7 LEDs, physical flash bounds, seed 3). When written, mean ΔE00
ambient / + matching / + complementary: tungsten 18.33 / 18.35 / 3.73, fluorescent 13.26 /
13.15 / 2.77, green 32.33 / 32.00 / 2.43, orange 34.67 / 34.55 / 19.91 (the target is out of
reach with bounded weights), underwater (ocean, 5 m, 1 m) 20.42 / 20.09 / 1.36. Under water,
red-channel SNR on the neutral patches 22.7 (von Kries) vs 40.2 (complementary re-capture at
the same exposure); chroma noise 3.07 vs 2.50.
"""

from __future__ import annotations

import argparse
import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli_common import UsageError
from msflash.lab import cli_colour_study, colour_study
from tests.acquisition.support.png_files import png_chunks
from tests.acquisition.support.report_pages import parse_report

ACCEPTANCE_AMBIENTS = ("tungsten", "fluorescent", "underwater")


@cache
def study(ambient: str) -> dict:
    return colour_study.study_ambient(ambient, seed=3, patch_px=10)


def run_cli(argv: list[str]) -> int:
    root = argparse.ArgumentParser(prog="msflash")
    cli_colour_study.register(root.add_subparsers(dest="command"))
    args = root.parse_args(argv)
    return int(args.handler(args))


class TestAcceptance:
    @pytest.mark.parametrize("ambient", ACCEPTANCE_AMBIENTS)
    def test_complementary_cuts_delta_e_by_a_third(self, ambient: str) -> None:
        delta_e = study(ambient)["delta_e"]
        before, after = delta_e["ambient"]["mean"], delta_e["complementary"]["mean"]
        assert before > 10  # a strong cast to begin with
        assert after <= 0.7 * before
        # The re-captured complementary image agrees with the synthesised one.
        assert delta_e["complementary-capture"]["mean"] == pytest.approx(after, abs=0.5)

    @pytest.mark.parametrize("ambient", colour_study.STUDY_AMBIENTS)
    def test_matching_keeps_the_cast(self, ambient: str) -> None:
        delta_e = study(ambient)["delta_e"]
        assert abs(delta_e["matching"]["mean"] - delta_e["ambient"]["mean"]) <= 1.0

    def test_underwater_red_snr_complementary_beats_von_kries(self) -> None:
        noise = study("underwater")["noise"]
        von_kries, complementary = noise["von_kries"], noise["complementary"]
        assert complementary["mean_snr"]["R"] > 1.3 * von_kries["mean_snr"]["R"]
        assert np.all(complementary["snr"]["R"] > von_kries["snr"]["R"])  # on every neutral patch
        assert complementary["mean_chroma_noise"] < von_kries["mean_chroma_noise"]
        assert noise["von_kries_gains"][0] > 1.5  # the balance amplified red

    def test_summary(self) -> None:
        summary = colour_study.delta_e_summary({name: study(name) for name in ACCEPTANCE_AMBIENTS})
        for values in summary.values():
            assert values["complementary_cut"] >= 0.3
            assert abs(values["matching_change"]) <= 1.0


class TestColourStudyCommand:
    def test_report_holds_the_fig9_table_and_noise(self, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
        out = tmp_path / "study"
        assert (
            run_cli(
                ["colour-study", "--ambients", "underwater,tungsten", "--patch-px", "8", "--out", str(out), "--json"]
            )
            == 0
        )
        payload = json.loads(capsys.readouterr().out)
        assert set(payload["delta_e"]) == {"underwater", "tungsten"}
        report = parse_report(out / "report.html")
        rows = report.tables["delta-e"]
        assert [row[0] for row in rows[1:]] == ["underwater", "tungsten"]
        for row in rows[1:]:
            assert float(row[3]) == pytest.approx(payload["delta_e"][row[0]]["complementary"], abs=0.006)
        assert "noise-underwater" in report.tables
        # Fig. 9 chart + 4 previews and a spectra plot per ambient + the Fig. 3 panel (3 images).
        assert len(report.embedded) == 1 + 2 * 5 + 3
        assert (out / "underwater" / "complementary-capture.exr").exists()
        # The figures also as PNG files beside the report, named in the JSON, the same bytes the report shows.
        assert set(payload["figures"]) == {"fig9.png", "fig3-snr.png", "underwater/spectra.png", "tungsten/spectra.png"}
        for relative, path in payload["figures"].items():
            data = Path(path).read_bytes()
            assert Path(path) == out / relative and png_chunks(data)["sRGB"] == b"\x00"
            assert data in report.embedded

    def test_bad_ambient(self) -> None:
        with pytest.raises(UsageError, match="--ambients 'moon'"):
            run_cli(["colour-study", "--ambients", "moon", "--json"])

    def test_cfa_frames_give_the_same_picture(self) -> None:
        result = colour_study.study_ambient("underwater", seed=1, patch_px=10, cfa="GRBG")
        assert result["delta_e"]["complementary"]["mean"] <= 0.3 * result["delta_e"]["ambient"]["mean"]
        assert result["noise"]["complementary"]["mean_snr"]["R"] > result["noise"]["von_kries"]["mean_snr"]["R"]
