"""One sequence, one estimate: every command reporting a sequence's ambient gives the same numbers.

``estimate`` and ``flash`` (default ``--method auto``, ``--model led``), ``estimate --method global``,
``run --rig replay:SEQ``, ``export`` (its CSV and JSON) and ``evaluate`` all take the ambient estimate
of a recorded sequence through ``acquisition/session/analysis.py`` (docs/architecture.md §5.2); their
numbers are compared bit for bit, on a simulated run's sequence and on one of the shared samples
(written by another tool). The live view's Fire and ``run`` on the sim rig report the estimate of the
sequence they recorded by the same route (the statistics accumulated as the frames arrived,
``session/estimate_stream.EstimateStream``, to which a sequence on disk is fed too): checked on the sim run.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main as msflash_main
from msflash.lab.study.local import make_scenario
from msflash.processing.frame_kernels import KERNELS_VARIABLE
from tests.lab.test_cli_local import SHAPE, write_scenario

SAMPLE = Path("/work/shared/samples/sample-rgb-tungsten")


def json_of(capsys: pytest.CaptureFixture[str], argv: list[str]) -> dict:
    """The JSON object ``msflash ARGV`` prints (exit status 0 asserted)."""
    capsys.readouterr()
    assert msflash_main(argv) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def csv_estimate(path: Path) -> np.ndarray:
    """The ``ambient estimate`` column of an exported spectra.csv."""
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    column = next(i for i, name in enumerate(rows[0]) if name.startswith("ambient estimate ["))
    return np.array([float(row[column]) for row in rows[1:]])


def every_route(sequence: Path, work: Path, capsys: pytest.CaptureFixture[str], chart: bool) -> dict[str, dict]:
    """Each command's spectrum (where it reports one) and ambient weights for ``sequence``."""
    seq = str(sequence)
    found: dict[str, dict] = {}
    auto = json_of(capsys, ["estimate", "--json", seq])
    assert auto["method"] == "global"  # auto kept the global model on these uniformly lit scenes
    found["estimate"] = auto
    found["estimate --method global"] = json_of(capsys, ["estimate", "--method", "global", "--json", seq])
    found["flash"] = {
        "ambient_weights": json_of(capsys, ["flash", "--mode", "complementary", "--json", seq])["ambient_weights"]
    }
    replay = work / "replay"
    capsys.readouterr()
    assert msflash_main(["run", "--rig", f"replay:{seq}", "--out", str(replay)]) == 0, capsys.readouterr().err
    found["run --rig replay"] = json.loads((replay / "estimate.json").read_text())
    exported = work / "export"
    json_of(capsys, ["export", "--to", "csv", "--out", str(exported), "--json", seq])
    spectra = json.loads((exported / "spectra.json").read_text())
    found["export"] = {
        "spectrum": csv_estimate(exported / "spectra.csv"),
        "ambient_weights": spectra["ambient_weights"],
    }
    if chart:
        evaluated = json_of(
            capsys, ["evaluate", "--chart", "macbeth", "--patch-px", "8", "--out", str(work / "ev"), "--json", seq]
        )
        found["evaluate"] = {"ambient_weights": evaluated["ambient_weights"]}
    return found


def assert_one_estimate(found: dict[str, dict]) -> None:
    reference = found["estimate"]
    for route, numbers in found.items():
        np.testing.assert_array_equal(numbers["ambient_weights"], reference["ambient_weights"], err_msg=route)
        if "spectrum" in numbers:
            np.testing.assert_array_equal(numbers["spectrum"], reference["spectrum"], err_msg=route)
        if "alpha" in numbers:
            assert numbers["alpha"] == reference["alpha"], route


def test_a_simulated_run_and_every_command_on_its_sequence_report_one_estimate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    assert msflash_main(["run", "--rig", "sim", "--scene", "macbeth", "--out", str(run)]) == 0
    found = every_route(run / "sequence", tmp_path, capsys, chart=True)
    # The run decided its flash from the statistics taken as frames arrived and reports them: the
    # recorded sequence's estimate to the last digit (one accumulator, the same frames in the same order).
    found["run --rig sim"] = json.loads((run / "estimate.json").read_text())
    assert_one_estimate(found)


def test_a_sample_from_another_tool_gives_one_estimate_through_every_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sample = tmp_path / SAMPLE.name
    shutil.copytree(SAMPLE, sample)
    assert_one_estimate(every_route(sample, tmp_path, capsys, chart=False))


def test_auto_choosing_the_local_model_says_so_and_keeps_the_shared_global_numbers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A scene lit by two ambients meeting at a boundary: auto picks the local model and says so (``estimate``
    and ``flash``); the global estimate under ``spectrum_global`` is the one ``--method global`` reports."""
    sequence = str(write_scenario(tmp_path / "boundary", make_scenario("boundary", 12, SHAPE)))
    auto = json_of(capsys, ["estimate", "--json", sequence])
    assert auto["method"] == "local" and auto["method_requested"] == "auto"
    assert auto["model_selection"]["chosen"] == "local"
    whole = json_of(capsys, ["estimate", "--method", "global", "--json", sequence])
    np.testing.assert_array_equal(auto["spectrum_global"], whole["spectrum"])
    np.testing.assert_array_equal(auto["ambient_weights_global"], whole["ambient_weights"])
    assert auto["alpha"] == whole["alpha"] and auto["spectrum"] != whole["spectrum"]
    flash = json_of(capsys, ["flash", "--mode", "complementary", "--json", sequence])
    assert flash["method"] == "local" and "tiles" in flash
    np.testing.assert_array_equal(flash["ambient_weights"], auto["ambient_weights"])


def test_the_live_views_fire_reports_the_estimate_of_the_sequence_it_recorded(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Fire in the live view (sim rig): the run folder's estimate.json (what the page plots) is what
    ``msflash estimate`` and ``export`` give for the sequence it recorded, to the last digit on one statistics
    route. The route is pinned: the fire's mix preview loads the compiled kernels, so an estimate taken after it in
    this process would take the compiled moments, which agree with the numpy route's to rounding only
    (processing.frame_kernels.statistics_compiled; tests/processing/test_frame_kernels.py holds that bound)."""
    monkeypatch.setenv(KERNELS_VARIABLE, "numpy")
    from tests.acquisition.app.test_live_http import TOKEN_HEADER, request
    from tests.acquisition.support.live import live_server, wait_until

    runs = tmp_path / "runs"
    with live_server(runs) as server:
        base = f"http://127.0.0.1:{server.port}"
        status, text = request("POST", base + "/api/sequence", {TOKEN_HEADER: server.token}, {"mode": "complementary"})
        assert status == 202
        run = runs / json.loads(text)["run"]

        def finished() -> dict | None:
            job = json.loads(request("GET", base + "/api/state")[1])["job"]
            return job if job["status"] in ("done", "failed") else None

        assert wait_until(finished, "the sequence to finish", timeout_s=240)["status"] == "done"
    found = {
        "estimate": json_of(capsys, ["estimate", "--json", str(run)]),
        "live fire": json.loads((run / "estimate.json").read_text()),
    }
    exported = tmp_path / "export"
    json_of(capsys, ["export", "--to", "csv", "--out", str(exported), "--json", str(run)])
    found["export"] = {
        "spectrum": csv_estimate(exported / "spectra.csv"),
        "ambient_weights": json.loads((exported / "spectra.json").read_text())["ambient_weights"],
    }
    assert_one_estimate(found)
