"""The harness's splits are disjoint, follow msflash's light split and never reach Natural-100."""

from __future__ import annotations

import numpy as np

from msflash.processing.light_library import library_lights
from tests.harness import cases, splits, tables


def test_the_shared_light_file_maps_onto_msflash_labels_and_values() -> None:
    from msflash.processing.light_library import light_library

    ours, theirs = tables.lights(), light_library()
    assert ours.names == theirs.names
    assert np.array_equal(ours.values, theirs.values)


def test_light_split_is_msflash_library_split_and_disjoint() -> None:
    tuning = {label for label, _ in splits.lights_of("tuning")}
    held_out = {label for label, _ in splits.lights_of("held_out")}
    assert not tuning & held_out
    assert tuning | held_out == {light.label for light in library_lights()}
    assert held_out == {light.label for light in library_lights() if light.split == "held_out"}


def test_camera_split_is_disjoint_by_identity_and_covers_every_camera() -> None:
    tuning, held_out = splits.cameras_of("tuning"), splits.cameras_of("held_out")
    assert set(tuning) | set(held_out) == set(tables.camera_names()) and len(tables.camera_names()) == 43
    assert not {tables.camera_identity(c) for c in tuning} & {tables.camera_identity(c) for c in held_out}
    assert "isetcam:NikonD1" in held_out and "NikonD1" in held_out  # one camera, two files, one side
    assert 0.2 < len(held_out) / len(tables.camera_names()) < 0.4


def test_surface_pools_are_disjoint_and_hold_no_natural100_surface() -> None:
    pools = {split: tables.surfaces(splits.surface_sets_of(split)) for split in splits.SPLITS}
    assert not set(pools["tuning"].names) & set(pools["held_out"].names)
    reference = tables.natural100()
    for pool in pools.values():
        visible = np.column_stack(
            [np.interp(reference.wavelengths_nm, pool.wavelengths_nm, column) for column in pool.values.T]
        )
        distance = np.abs(visible[:, :, None] - reference.values[:, None, :]).max(axis=0)
        assert distance.min() > tables.NATURAL100_TOLERANCE
    # Vrhel Objects holds 82 Natural-100 surfaces verbatim: they are gone, the rest stay.
    assert sum(name.startswith("objects:") for name in pools["tuning"].names) == 170 - 82


def test_every_case_uses_only_its_splits_light_camera_and_surfaces() -> None:
    for split in splits.SPLITS:
        lights = {label for label, _ in splits.lights_of(split)}
        for case in cases.cases_of(split):
            assert case.split == split
            assert case.light in lights
            assert case.camera in splits.cameras_of(split)
            assert case.surface_sets == splits.surface_sets_of(split)


def test_case_lists_are_deterministic_and_span_every_family() -> None:
    for split in splits.SPLITS:
        listed = cases.cases_of.__wrapped__(split)
        assert listed == cases.cases_of(split) and len(listed) == cases.CASES_PER_SPLIT
        assert {c.cfa for c in listed} == {None, "RGGB", "BGGR", "GRBG", "GBRG"}
        assert {c.bits for c in listed} == {10, 12, 14, 16}
        assert {c.grid for c in listed} == set(cases.GRIDS)
        assert {c.leds for c in listed} == set(tables.led_set_names())
        assert {"led", "fluorescent", "incandescent", "discharge"} <= {c.light_type for c in listed}
        assert {c.exposures for c in listed} == {"equal", "unequal"}
        assert any(c.specular for c in listed) and any(c.vignetting < 1 for c in listed)
        assert min(c.ratio for c in listed) < 0.5 and max(c.ratio for c in listed) > 2
