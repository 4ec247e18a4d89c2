"""The physics suite (issue 30, item 3): lights, cameras and splits made from physics, and held apart."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.harness import metrics, physics_cases, physics_lights, tables
from tests.harness.physics_cameras import physics_camera
from tests.harness.run import run_case
from tests.harness.variants import VARIANTS


def _overlap(a: tuple[float, float], b: tuple[float, float]) -> float:
    return min(a[1], b[1]) - max(a[0], b[0])


def test_every_parameter_interval_of_the_two_splits_is_disjoint() -> None:
    for kind, parameters in physics_lights.RANGES.items():
        for name, by_split in parameters.items():
            for a in by_split["tuning"]:
                for b in by_split["held_out"]:
                    assert _overlap(a, b) <= 0, (kind, name, a, b)


@pytest.mark.parametrize("family", physics_lights.FAMILIES)
@pytest.mark.parametrize("split", ["tuning", "held_out"])
def test_every_family_makes_finite_non_negative_lights_with_the_split_parameters(family: str, split: str) -> None:
    rng = np.random.default_rng(7)
    for _ in range(6):
        light = physics_lights.draw_light(family, split, rng)
        for kind, params in ((light.kind, light.params), (light.second_kind, light.second_params)):
            for name, value in params:
                if name == "shape_seed":
                    continue
                intervals = physics_lights.RANGES[kind][name][split]
                assert any(low <= value <= high for low, high in intervals), (kind, name, value)
        spd = light.energy()
        assert spd.shape == physics_lights.FINE.shape and np.all(np.isfinite(spd)) and spd.min() >= 0
        assert spd.max() == pytest.approx(1.0)


def test_physics_at_known_wavelengths() -> None:
    bb = physics_lights.planck(5778.0)
    assert 480 <= physics_lights.FINE[np.argmax(bb)] <= 520  # Wien: 2.898e6 nm K / 5778 K ≈ 502 nm
    d65 = physics_lights.daylight(6504.0)
    import colour

    reference = colour.SDS_ILLUMINANTS["D65"]
    truth = np.interp(physics_lights.FINE, reference.wavelengths, reference.values)
    assert np.max(np.abs(d65 / d65[physics_lights.FINE == 560] - truth / truth[physics_lights.FINE == 560])) < 0.02
    mercury = physics_lights.spectrum("halophosphate", {"manganese": 0.0, "mercury": 1.0, "shape_seed": 1.0})
    assert physics_lights.FINE[np.argmax(mercury)] in (436.0, 546.0)


def test_the_slit_keeps_a_line_between_two_samples() -> None:
    line = physics_lights._line(545.0, 1.0, 0.0)
    grid = np.arange(400.0, 701.0, 10.0)
    seen = physics_lights.on_grid(line, grid)
    assert seen[grid == 540][0] == pytest.approx(seen[grid == 550][0], rel=1e-6) and seen.max() > 0
    assert np.interp(grid, physics_lights.FINE, line)[grid == 540][0] < 1e-6  # point sampling would lose it


def test_physics_cameras_are_deterministic_and_shaped_like_cameras() -> None:
    nm = np.arange(380.0, 781.0, 1.0)
    camera = physics_camera("physics:h04", nm)
    assert np.array_equal(camera, physics_camera("physics:h04", nm))
    assert not np.array_equal(camera, physics_camera("physics:t04", nm))
    peaks = nm[np.argmax(camera, axis=0)]
    assert peaks[0] > peaks[1] > peaks[2]  # R, G, B
    assert camera[nm > 720].max() < 0.05  # the IR cut


def test_the_cases_hold_apart_lights_cameras_and_surfaces_and_are_balanced() -> None:
    tuning, held_out = physics_cases.physics_cases_of("tuning"), physics_cases.physics_cases_of("held_out")
    assert not {c.camera for c in tuning} & {c.camera for c in held_out}
    assert not set(tables.surfaces(tuning[0].surface_sets).names) & set(tables.surfaces(held_out[0].surface_sets).names)
    for cases in (tuning, held_out):
        for family in physics_lights.FAMILIES:
            assert sum(c.light_type == family for c in cases) == len(cases) // len(physics_lights.FAMILIES)
        for layout in physics_cases.LAYOUTS:
            assert sum(c.cfa == layout for c in cases) == len(cases) // len(physics_cases.LAYOUTS)
    assert physics_cases.light_of(held_out[3]).family == held_out[3].light_type


def test_a_physics_case_renders_and_is_estimated_end_to_end(tmp_path) -> None:
    case = physics_cases.physics_cases_of("held_out")[1]
    result = run_case(case, [VARIANTS["default"]], tmp_path)
    measured = result.of("default")
    assert measured is not None and not measured.error and math.isfinite(measured.ratio)
    assert 0 < result.bound and measured.ratio < 3
    assert metrics.summarise([measured.ratio]).count == 1


def test_the_failure_map_counts_warned_misses_per_light_kind() -> None:
    from tests.harness.report import failure_map
    from tests.harness.run import CaseResult, Measured

    cases = physics_cases.physics_cases_of("tuning")[:3]
    results = [
        CaseResult(cases[0], 0.1, (Measured("a", ratio=1.5, warnings=("w",)), Measured("b", ratio=1.4))),
        CaseResult(cases[1], 0.1, (Measured("a", ratio=1.6, warnings=()), Measured("b", ratio=0.9))),
        CaseResult(cases[2], 0.1, (Measured("a", ratio=0.9, warnings=()), Measured("b", ratio=0.8))),
    ]
    variants = [VARIANTS["default"].__class__("a"), VARIANTS["default"].__class__("b")]
    lines = failure_map(results, variants, by="light type")
    cells = {line.split(" | ")[0].strip("| "): line for line in lines[2:]}
    assert len(lines) == 2 + len({c.light_type for c in cases})
    if cases[0].light_type != cases[1].light_type:
        assert "1 / 1" in cells[cases[0].light_type] and "0 / 1" in cells[cases[1].light_type]
        assert "— / 1" in cells[cases[0].light_type]  # b cannot warn


def test_the_chart_applies_the_family_rule_and_the_shipped_thresholds() -> None:
    from msflash.processing.family_checks import LED_WARNING
    from msflash.processing.light_families import CHECK_TEMPERATURE, SIMPLER_WITHIN
    from tests.harness import families_chart

    rows = [
        {"held_out_clean": "0.010", "n_parameters": "12", "ratio": "0.5"},
        {"held_out_clean": str(0.010 * (1 + SIMPLER_WITHIN / 2)), "n_parameters": "2", "ratio": "0.9"},
    ]
    assert families_chart._choose(rows)["ratio"] == "0.9"  # the simplest within the margin
    record = {"auto": "led", "led:ratio": 1.5, "prior:ratio": 0.5, "family:ratio": 0.5, "auto:ratio": 1.5}
    tau = f"{CHECK_TEMPERATURE:g}"
    record.update({f"d:led:chosen:{tau}": LED_WARNING + 0.1, f"d:prior:chosen:{tau}": 0.1, f"spread:chosen:{tau}": 0.1})
    scores = families_chart.warning_scores({"x": record})
    score, miss, threshold = scores["led"]
    assert miss[0] and score[0] >= threshold
    auto_score, auto_miss, auto_threshold = scores["auto"]
    assert auto_miss[0] and auto_score[0] >= auto_threshold  # auto kept the LEDs: their check applies
