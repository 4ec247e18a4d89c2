"""Tests of the failure, Pareto and Figs. 6–7 studies (lab.study.failure/pareto/cameras).

Fast reduced versions (one camera, one ambient, one noise seed, a few levels) run in seconds and
pin the trends and whether the estimator's specific warnings (saturation, misfit) fire in the clear
failure cases. The miss-risk warning (processing.model_error) is judged on the harness instead
(docs/ambient-harness.md): in this study's world it also fires on the daylight baseline (expected
ratio 1.09–1.12 against a real 0.95), a false alarm. Where the estimator does *not* warn in a clear
failure, the test is a strict xfail that records the finding: it starts passing — and so fails the
suite, prompting an update — once the estimator warns there. Full runs are behind ``-m study``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from msflash.lab.study.cameras import camera_spread, run_cameras, run_xy
from msflash.lab.study.failure import FACTORS, led_fill, run_failure, with_line
from msflash.lab.study.noisy import make_world, render_stack
from msflash.lab.study.pareto import pareto_front, run_pareto
from msflash.processing import datasets, lights
from msflash.processing.accumulate import accumulate_statistics

CAMERA = "Canon 50D"


def _failure(factors: dict, ambients=("daylight",), seeds=1) -> dict:
    return run_failure(factors=factors, cameras=[CAMERA], ambients=list(ambients), seeds=seeds)


def _by_level(result: dict, factor: str) -> dict:
    return {row["level"]: row for row in result["summary"][factor]}


def test_heavy_saturation_warns():
    rows = _by_level(_failure({"saturation": [1.0, 16.0]}), "saturation")
    assert rows[1.0]["flag_rates"]["saturation"] == 0
    assert rows[16.0]["warned_rate"] == 1 and rows[16.0]["flag_rates"]["saturation"] == 1
    assert rows[16.0]["saturated_fraction_median"] > 0.5


def test_large_motion_warns_through_the_residual():
    rows = _by_level(_failure({"motion": [0, 8]}), "motion")
    assert rows[0]["flag_rates"]["residual"] == 0
    assert rows[8]["warned_rate"] == 1 and rows[8]["flag_rates"]["residual"] == 1
    assert rows[8]["relative_residual_median"] > 0.5


@pytest.mark.xfail(
    strict=True,
    reason=(
        "finding: a 570 nm line between the LEDs carrying 95 % of the light: RMSE 0.48 against an LED bound of "
        "0.37 (1.31x), unwarned. The misfit (beyond the noise) stays below 0.2 and the reference lights whose "
        "estimates look like this one came out 0.79x their bound: none of them is a line light"
    ),
)
def test_ambient_in_the_gap_between_leds_warns_when_it_dominates():
    rows = _by_level(_failure({"line_570nm": [0.0, 0.95]}), "line_570nm")
    assert rows[0.95]["error_mean"] > rows[0.0]["error_mean"] + 0.1
    assert rows[0.95]["warned_rate"] == 1


def test_ambient_far_outside_the_leds_is_a_silent_failure():
    """The finding above, pinned directly: large error, residual at its baseline value."""
    rows = _by_level(_failure({"line_700nm": [0.0, 0.5]}), "line_700nm")
    assert rows[0.5]["error_mean"] > rows[0.0]["error_mean"] + 0.2
    assert rows[0.5]["relative_residual_median"] < 0.05


def test_dead_led_warns():
    """A dead LED (frame = ambient + noise) is flagged by the LED fill signal (mean/RMS of its image)."""
    rows = _by_level(_failure({"dead_led": [3]}), "dead_led")
    assert rows[3]["warned_rate"] == 1


def test_the_proposed_led_fill_signal_flags_a_dead_led():
    world = make_world(datasets.paper_cameras()[CAMERA], lights.ambient_spectrum("tungsten"))
    fills = {}
    for dead in (None, 0, 3, 6):
        ambient, frames, spec = render_stack(world, np.random.default_rng(5), dead_led=dead)
        fills[dead] = led_fill(accumulate_statistics(ambient, frames, spec, bin_factor=4))
    assert fills[None] > 0.3
    assert all(abs(fills[k]) < 0.1 for k in (0, 3, 6))


def test_noise_raises_the_residual_and_warns_at_low_light():
    result = _failure({"exposure": [1.0, 1 / 16, 1 / 1024], "ambient_to_flash": [0.5, 5.0, 50.0]})
    exposure = _by_level(result, "exposure")
    residuals = [exposure[level]["relative_residual_median"] for level in (1.0, 1 / 16, 1 / 1024)]
    assert residuals[0] < residuals[1] < residuals[2]
    assert exposure[1 / 1024]["warned_rate"] == 1
    ratio = _by_level(result, "ambient_to_flash")
    assert (
        ratio[0.5]["relative_residual_median"]
        < ratio[5.0]["relative_residual_median"]
        < ratio[50.0]["relative_residual_median"]
    )
    assert ratio[50.0]["warned_rate"] == 1 and ratio[50.0]["error_mean"] > ratio[0.5]["error_mean"]


def test_fewer_leds_and_fewer_surfaces_cost_accuracy():
    result = _failure({"n_leds": [7, 3], "surfaces": [110, 1]}, ambients=("daylight", "fluorescent"))
    leds = _by_level(result, "n_leds")
    assert leds[3]["error_mean"] > leds[7]["error_mean"]
    assert leds[3]["bound_mean"] > leds[7]["bound_mean"]
    surfaces = _by_level(result, "surfaces")
    assert surfaces[1]["error_mean"] > surfaces[110]["error_mean"]


def test_failure_result_is_json_ready_with_a_confusion_summary():
    result = _failure({"motion": [0, 4], "dead_led": [-1, 2]})
    json.dumps(result, allow_nan=True)
    table = result["confusion"]["all"]
    assert sum(table.values()) == len(result["records"]) == 4
    assert set(result["confusion"]["per_factor"]) == {"motion", "dead_led"}
    assert all(set(FACTORS[name]["levels"]) >= set(levels["levels"]) for name, levels in result["factors"].items())


def test_with_line_moves_the_requested_fraction_of_photons():
    line = with_line(lights.ambient_spectrum("daylight"), 700.0, 0.5)
    values = line.values[:, 0]
    assert values.sum() == pytest.approx(1.0)
    assert values[-1] > 0.35  # the 700 nm sample holds most of the line


def test_pareto_front_marks_non_dominated_points():
    errors = np.array([0.3, 0.2, 0.25, 0.2, np.nan])
    times = np.array([1.0, 5.0, 6.0, 4.0, 0.1])
    assert pareto_front(errors, times).tolist() == [True, False, False, True, False]


def test_tiny_pareto_runs_and_marks_the_default():
    result = run_pareto(
        cameras=[CAMERA],
        ambients=["daylight"],
        seeds=1,
        patch_px=12,
        repeats=1,
        samplings=("all", "mask_1e3", "gather_1e3", "bin4", "patch_means"),
        solvers=("nonneg", "tikhonov_auto"),
    )
    assert len(result["points"]) == 10
    assert result["front"] and all(p["on_front"] for p in result["front"])
    assert result["default"]["solver"] == "tikhonov_auto" and result["default"]["sampling"] == "bin4"
    assert all(np.isfinite(p["error_mean"]) for p in result["points"])
    # block sums cut the errors-in-variables bias of noisy LED-only images
    errors = {(p["solver"], p["sampling"]): p["error_mean"] for p in result["points"]}
    assert errors[("tikhonov_auto", "bin4")] < errors[("tikhonov_auto", "all")]
    json.dumps(result)


def test_camera_spread_is_zero_for_identical_estimates_and_grows_with_differences():
    same = np.tile(np.linspace(0, 1, 31), (4, 1))
    assert camera_spread(same) == 0
    noisy = same + np.random.default_rng(0).normal(0, 0.05, same.shape)
    assert 0.02 < camera_spread(noisy) < 0.08


def test_tiny_cameras_and_xy_studies_run():
    cameras = run_cameras(n_leds_list=(3, 7), cameras=3, illuminants=2)
    assert len(cameras["camera_spread"]) == 2 and all(np.isfinite(cameras["camera_spread"]))
    assert cameras["failures"] == 0
    json.dumps(cameras)
    xy = run_xy(n_leds_list=(3, 7), cameras=2, illuminants=3)
    assert len(xy["xy"]) == 3 and len(xy["spectrum_rmse"][0]) == 2
    assert all(row[1] <= row[0] + 0.05 for row in xy["bound"])  # 7 LEDs fit at least about as well as 3
    json.dumps(xy)


def _parser():
    from tests.lab.study.test_study import _parser as parser

    return parser()


@pytest.mark.parametrize(
    "argv, key",
    [
        (["failure", "--factors", "motion", "--cameras", "1", "--ambients", "daylight", "--seeds", "1"], "summary"),
        (
            [
                "pareto",
                "--cameras",
                "1",
                "--ambients",
                "daylight",
                "--seeds",
                "1",
                "--patch-px",
                "10",
                "--repeats",
                "1",
                "--samplings",
                "all,mask_1e3,bin4",
            ],
            "points",
        ),
        (["cameras", "--cameras", "2", "--illuminants", "2", "--leds", "3,7"], "camera_spread"),
        (["xy", "--cameras", "2", "--illuminants", "3", "--leds", "5"], "spectrum_rmse"),
    ],
)
def test_cli_new_studies_write_json_and_png(tmp_path, capsys, argv, key):
    from tests.acquisition.support.png_files import png_chunks

    args = _parser().parse_args(["study", *argv, "--out", str(tmp_path), "--scheduler", "none"])
    assert args.handler(args) == 0
    saved = json.loads((tmp_path / f"{argv[0]}.json").read_text())
    assert key in saved
    assert png_chunks((tmp_path / f"{argv[0]}.png").read_bytes())["sRGB"] == b"\x00"  # a PNG declared sRGB
    assert capsys.readouterr().out.strip()


def test_cli_failure_rejects_an_unknown_factor():
    from msflash.acquisition.app.cli_common import UsageError
    from msflash.processing.errors import SpectralDataError

    args = _parser().parse_args(["study", "failure", "--factors", "nonsense", "--scheduler", "none"])
    with pytest.raises((UsageError, SpectralDataError)):
        args.handler(args)


@pytest.mark.study
def test_full_failure_study():
    result = run_failure()
    summary = {factor: {row["level"]: row for row in rows} for factor, rows in result["summary"].items()}
    assert summary["saturation"][16.0]["warned_rate"] == 1
    assert summary["motion"][8]["warned_rate"] == 1
    assert summary["line_570nm"][0.95]["warned_rate"] >= 0.8
    assert summary["n_leds"][3]["error_mean"] > summary["n_leds"][7]["error_mean"]


@pytest.mark.study
def test_full_pareto_study():
    result = run_pareto()
    assert result["default"] is not None and result["front"]
    errors = {(p["solver"], p["sampling"]): p["error_mean"] for p in result["points"]}
    assert errors[("tikhonov_auto", "bin4")] < errors[("tikhonov_auto", "all")]


@pytest.mark.study
def test_full_cameras_study():
    result = run_cameras()
    assert result["config"]["n_cameras"] == 34 and result["failures"] == 0
    assert result["camera_spread"][2] < result["camera_spread"][0]  # 5 LEDs vs 3
