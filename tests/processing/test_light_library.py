"""The light library's split: fixed by the labels, copies of one source on one side, no leak into the prior."""

import numpy as np

from msflash.processing.light_library import (
    NEAR_COPY_COSINE,
    library_lights,
    light_library,
    light_type,
    lights_of,
    near_copy_groups,
    prior_training_lights,
    without_near_copies,
)


def _unit(values: np.ndarray) -> np.ndarray:
    return values / np.linalg.norm(values, axis=0)


def test_library_reads_all_401_lights_in_energy():
    library = light_library()
    assert library.count == 401 and library.unit == "energy"
    assert library.wavelengths_nm[0] == 380 and library.wavelengths_nm[-1] == 780


def test_split_holds_out_about_a_third_of_every_common_type_and_is_fixed_by_labels():
    lights = library_lights()
    held = [light for light in lights if light.split == "held_out"]
    assert 100 <= len(held) <= 160
    for kind in ("led", "fluorescent", "incandescent", "discharge"):
        of_kind = [light for light in lights if light.light_type == kind]
        share = sum(light.split == "held_out" for light in of_kind) / len(of_kind)
        assert 0.15 <= share <= 0.7, kind  # incandescent: 23 of 37 (the Houser blackbody models are one group)
    # copies of one source never straddle the split
    for group in {light.group for light in lights}:
        assert len({light.split for light in lights if light.group == group}) == 1


def test_prior_training_lights_hold_no_near_copy_of_a_held_out_light():
    held, prior = lights_of("held_out"), prior_training_lights()
    visible = (held.wavelengths_nm >= 400) & (held.wavelengths_nm <= 700)
    similarity = _unit(prior.values[visible]).T @ _unit(held.values[visible])
    assert similarity.max() < NEAR_COPY_COSINE
    assert set(prior.names) <= set(lights_of("tuning").names) and prior.count >= 120


def test_without_near_copies_drops_a_copy_of_a_held_out_light_in_photons():
    held = lights_of("held_out")
    copy = held.replace(values=held.values[:, :1] * 3.0, names=("copy",)).to_unit("photons")
    assert without_near_copies(copy).count == 0


def test_near_copy_groups_are_transitive():
    x = np.linspace(0, 1, 50)
    a, b, c = 1 + 0.0 * x, 1 + 0.03 * x, 1 + 0.06 * x
    groups = near_copy_groups(np.column_stack([a, b, c, np.sin(9 * x) + 1.5]), threshold=0.9995)
    assert groups[0] == groups[1] == groups[2] != groups[3]


def test_light_type_reads_labels():
    assert light_type("NIST 11: Incandescent") == "incandescent"
    assert light_type("NIST 35: CIE F2*") == "fluorescent"
    assert light_type("Slide 15: Cree LLS") == "led"
    assert light_type("NIST 8: Mercury") == "discharge"
    assert light_type("MCRI-58: WGR4k") == light_type("MCRI-51: CRI(WGARC)3k") == "led"  # LED mixes named by CCT
    assert light_type("Houser: 3000 K") == light_type("MCRI-44: Halogen3k") == "incandescent"
