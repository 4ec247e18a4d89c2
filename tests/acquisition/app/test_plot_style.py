"""The one palette and unit, and figures that can be read: no panel over another, no label cut off."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from msflash.acquisition.app.plot_style import PALETTE, SERIES, figure_png, pyplot
from msflash.lab.cli_study import xy_figure
from msflash.lab.cli_support import relative_power
from tests.acquisition.support.png_files import png_chunks


def test_the_palette_gives_each_role_its_own_colour() -> None:
    roles = [name for name in PALETTE.__dataclass_fields__]
    colours = [PALETTE.of(name) for name in roles]
    assert len(set(colours)) == len(colours)  # no two things share a colour
    assert PALETTE.of("matching-capture") == PALETTE.matching
    assert set(colours) - {PALETTE.led_fit, PALETTE.target} <= set(SERIES)  # Okabe & Ito's, colour-blind safe
    with pytest.raises(KeyError, match="no colour for 'flash'"):
        PALETTE.of("flash")


def test_spectra_are_drawn_in_energy_units_whatever_they_were_given_in() -> None:
    wavelengths = np.arange(400.0, 701.0, 10.0)
    photons = np.ones(wavelengths.size)
    energy = relative_power(wavelengths, photons, "photons")
    # A flat photon spectrum carries energy ∝ 1/λ: highest at 400 nm, 400/700 of it at 700 nm.
    assert energy[0] == pytest.approx(1.0) and energy[-1] == pytest.approx(400 / 700)
    assert relative_power(wavelengths, 2 * photons, "energy") == pytest.approx(np.ones(wavelengths.size))


def _xy_result(counts: list[int]) -> dict:
    xy = [[x, y] for x in (0.11, 0.22, 0.33, 0.44) for y in (0.11, 0.22, 0.33, 0.44) if x + y < 0.8]
    rng = np.random.default_rng(0)
    return {
        "n_leds": counts,
        "xy": xy,
        "spectrum_rmse": rng.uniform(0.02, 0.3, size=(len(xy), len(counts))).tolist(),
    }


@pytest.mark.parametrize("counts", [[5], [3, 4, 5, 6, 7]], ids=["one", "five"])
def test_study_xy_panels_do_not_overlap_and_every_label_is_inside_the_figure(counts: list[int]) -> None:
    """`study xy` drew five panels in one row whose tick labels ran into the next panel and whose x labels
    were cut at the bottom edge."""
    figure = xy_figure(_xy_result(counts))
    plt = pyplot()
    try:
        figure.canvas.draw()
        renderer = figure.canvas.get_renderer()
        page = figure.bbox
        shown = [axis for axis in figure.axes if axis.get_visible() and axis.axison]
        boxes = [axis.get_tightbbox(renderer) for axis in shown]  # the panel with its ticks, labels and title
        for box in boxes:
            assert box.x0 >= page.x0 - 1 and box.y0 >= page.y0 - 1, box
            assert box.x1 <= page.x1 + 1 and box.y1 <= page.y1 + 1, box
        for first, second in itertools.combinations(boxes, 2):
            overlap_x = min(first.x1, second.x1) - max(first.x0, second.x0)
            overlap_y = min(first.y1, second.y1) - max(first.y0, second.y0)
            assert overlap_x <= 0 or overlap_y <= 0, (first, second)
        panels = [axis for axis in shown if axis.get_title().endswith("LEDs")]
        assert [axis.get_title() for axis in panels] == [f"{n} LEDs" for n in counts]
        assert sum(axis.get_xlabel() == "CIE 1931 x" for axis in panels) == min(len(counts), 3)  # each column's
        data = figure_png(figure)
    finally:
        plt.close(figure)
    assert png_chunks(data)["sRGB"] == b"\x00"
