"""Issue 29 item 5: a chart is not its reference data, and uneven light costs no accuracy.

The sequences come from an independent render (``tests/harness/chart_render.py``: the authors'
Macbeth chart and LEDs, a camera left out of the prior, Poisson noise, a 12 % lens falloff toward
the corners). Held-out camera: Aptina MT9M031 (nothing was tuned on it).
"""

from __future__ import annotations

import pytest

from tests.harness import chart_render


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("independent-chart")


def test_the_authors_chart_with_lens_falloff_is_fitted_within_the_bound(folder):
    rmse, refusal = chart_render.calibrate(folder, "AptinaMT9M031", 0.12, str(chart_render.AUTHORS_CHART), flat=False)
    assert refusal == "" and rmse is not None and rmse <= 0.04


def test_assuming_flat_light_under_falloff_is_what_failed(folder):
    rmse, refusal = chart_render.calibrate(folder, "AptinaMT9M031", 0.12, str(chart_render.AUTHORS_CHART), flat=True)
    assert rmse is None or rmse > 0.04, "the render's falloff no longer matters: the test proves nothing"


def test_the_shipped_reference_of_another_chart_is_refused_naming_patches(folder):
    rmse, refusal = chart_render.calibrate(folder, "AptinaMT9M031", 0.0, "macbeth", flat=False)
    assert rmse is None
    assert "patches that disagree most: patch " in refusal and "measure it (msflash calibrate chart)" in refusal
    assert "--chart FILE.csv" in refusal
