"""The warning-evidence study (tests/harness/warning_study.py, warning_rules.py): its ROC, its fold halves and one
real case's record."""

from __future__ import annotations

import math

import numpy as np

from tests.harness import warning_rules
from tests.harness.warning_study import HALVES, _fold_subset
from tests.processing.test_light_families import GRID, _statistics


def test_the_roc_and_the_operating_point() -> None:
    miss = np.array([True, True, False, False, False, False, False])
    area, recall, threshold, alarms = warning_rules.roc(np.array([9.0, 8, 1, 2, 3, 4, 5]), miss)
    assert (area, recall, threshold, alarms) == (1.0, 1.0, 8.0, 0.0)
    area, recall, _, alarms = warning_rules.roc(np.array([0.0, 1, 1, 2, 3, 4, 5]), miss)
    assert area < 0.1 and recall == 0.0  # the misses score lowest: no threshold at ≤ 20 % false alarms finds them
    assert math.isnan(warning_rules.roc(np.ones(3), np.zeros(3, bool))[0])


def test_the_halves_are_disjoint_and_add_up_to_the_frame() -> None:
    statistics = _statistics(np.ones(GRID.size), seed=1)
    first, second = (_fold_subset(statistics, half) for half in HALVES)
    assert not set(HALVES[0]) & set(HALVES[1]) and first.n_folds + second.n_folds == statistics.n_folds
    total = statistics.moments.total()
    for name in ("ff", "fa", "aa"):
        together = getattr(first.moments, name).sum(0) + getattr(second.moments, name).sum(0)
        np.testing.assert_allclose(together, getattr(total, name)[0])
    assert first.n_blocks + second.n_blocks == statistics.n_blocks


def test_a_real_case_gives_every_score_and_the_shipped_checks(tmp_path) -> None:  # noqa: ANN001
    from msflash.processing.family_checks import paper_rmse
    from tests.harness.cases import select_cases
    from tests.harness.warning_study import study_case

    record = study_case(select_cases("tuning", quick=True)[0], tmp_path)
    assert len(record["halves"]) == 2 and len(record["jackknife"]) == 5
    assert {split: len(halves) for split, halves in record["surface_halves"].items()} == {"colour": 2, "brightness": 2}
    scores = warning_rules.features(record)
    for model in warning_rules.MODELS:
        assert {"shipped", "half:full/own", "jack:std/own", "null0.5", "blind"} <= set(scores[model])
        assert all(isinstance(value, float) for value in scores[model].values())
    # The LEDs' shipped score is processing.family_checks.predicted_ratio's: the distance over the family's bound.
    unit = np.asarray(record["unit"])
    family = np.asarray(record["family_spectrum"]) * unit
    from msflash.processing.family_checks import led_bound

    expected = paper_rmse(np.asarray(record["led_seq"]), family) / led_bound(np.asarray(record["led_spd"]), family)
    assert scores["led"]["shipped"] == expected
    assert record["ratio"]["family"] > 0 and math.isfinite(record["ratio"]["led"])
