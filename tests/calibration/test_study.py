"""The full acceptance study: leave-one-camera-out over the 34 cameras (marker ``study``)."""

from __future__ import annotations

from functools import cache

import pytest

from calibration.validation import leave_one_camera_out, summarise


@cache
def full_summary() -> dict:
    return summarise(leave_one_camera_out())


@pytest.mark.study
def test_leave_one_camera_out_bound_and_flash():
    summary = full_summary()
    assert summary["cameras"] == 34
    assert summary["mean_rmse_prior"] <= 0.05
    assert summary["flash_delta_e_max"] <= 1.0


@pytest.mark.study
@pytest.mark.xfail(strict=True, reason="issue 7 asks ≥ 30 % better than smoothness alone; measured 18 % "
                                       "(0.0148 vs 0.0180, seed 0) — not met yet")
def test_leave_one_camera_out_prior_beats_smoothness_by_30_percent():
    assert full_summary()["improvement"] >= 0.30
