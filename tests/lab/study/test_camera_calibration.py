"""The full acceptance study: leave-one-camera-out over the 34 cameras, 5 noise seeds (marker ``study``)."""

from __future__ import annotations

from functools import cache

import pytest

from msflash.lab.study.camera_calibration import STUDY_SEEDS, leave_one_camera_out_seeds, summarise


@cache
def full_summary() -> dict:
    return summarise(leave_one_camera_out_seeds(STUDY_SEEDS))


@pytest.mark.study
def test_leave_one_camera_out_bound_and_flash():
    summary = full_summary()
    assert summary["cameras"] == 34 and summary["seeds"] == list(STUDY_SEEDS)
    assert summary["families"]["Jiang"]["cameras"] == 28 and summary["families"]["ISETCam"]["cameras"] == 6
    assert all(seed["mean_rmse_prior"] <= 0.05 for seed in summary["per_seed"].values())
    assert summary["flash_delta_e_max"] <= 1.0


@pytest.mark.study
def test_the_prior_beats_smoothness_on_every_seed():
    assert all(seed["improvement"] > 0.15 for seed in full_summary()["per_seed"].values())


@pytest.mark.study
@pytest.mark.xfail(
    strict=True,
    reason="issue 7 asks ≥ 30 % better than smoothness alone; measured 22 % over 5 seeds "
    "(0.0138 vs 0.0179; seed 0: 0.0146 vs 0.0180) — not met, see docs/calibration.md",
)
def test_leave_one_camera_out_prior_beats_smoothness_by_30_percent():
    assert full_summary()["improvement"] >= 0.30
