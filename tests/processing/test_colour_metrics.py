"""Colour metrics (patch statistics, CIEDE2000 against the chart under D65, von Kries, noise) and rendering."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from msflash.processing import colour_metrics as cm
from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.image_formation import expected_response, surface_responses
from msflash.processing.render import (
    camera_to_xyz_matrix,
    demosaic_bilinear,
    demosaic_superpixel,
    reflectances_to_xyz,
    srgb_preview,
)
from msflash.processing.scenes import chart_scene
from msflash.processing.sensor import mosaic
from msflash.processing.spectra import DEFAULT_GRID

GRID = DEFAULT_GRID


@cache
def world() -> tuple:
    """Macbeth chart, the sim camera (photons), D65, the fitted matrix and the reference chart."""
    chart = datasets.macbeth().resample(GRID)
    camera = datasets.isetcam_camera("NikonD100").resample(GRID).to_unit("photons")
    d65 = datasets.illuminant("D65", GRID)
    matrix = camera_to_xyz_matrix(camera, chart, d65.to_unit("photons"))
    return chart, camera, d65, matrix, cm.reference_chart(chart, d65)


def camera_means(illuminant_name: str) -> np.ndarray:
    chart, camera, *_ = world()
    return surface_responses(chart, datasets.illuminant(illuminant_name, GRID), camera)


class TestPatches:
    def test_usable_labels_drop_edges_and_excluded_pixels(self) -> None:
        labels = np.repeat(np.array([[0, 0, 0, 0, 1, 1, 1, 1]]), 6, axis=0)
        excluded = np.zeros(labels.shape, dtype=bool)
        excluded[0, 0] = True
        usable = cm.usable_labels(labels, 1, excluded)
        assert usable[3].tolist() == [0, 0, 0, -1, -1, 1, 1, 1]
        assert usable[0, 0] == -1 and usable[0, 1] == -1 and usable[0, 2] == 0
        assert cm.usable_labels(labels, 0).tolist() == labels.tolist()

    def test_patch_means_of_rgb_and_of_the_mosaic_agree(self) -> None:
        chart, camera, d65, *_ = world()
        scene = chart_scene(chart, patch_px=6, border_px=2)
        rgb = expected_response(scene, d65, camera, 1.0)
        labels = cm.usable_labels(scene.labels, 1)
        from_rgb = cm.patch_means(rgb, labels, 24)
        for cfa in ("RGGB", "BGGR", "GRBG", "GBRG"):
            assert cm.patch_means(mosaic(rgb, cfa), labels, 24, cfa) == pytest.approx(from_rgb, rel=1e-12)
        assert from_rgb == pytest.approx(surface_responses(chart, d65, camera), rel=1e-12)

    def test_patch_without_pixels_is_an_error(self) -> None:
        with pytest.raises(SpectralDataError, match="patch 1: 0 usable pixels.*patch-px"):
            cm.patch_means(np.ones((2, 2, 3)), np.zeros((2, 2), dtype=int), 2)


class TestDeltaE:
    @pytest.mark.parametrize(
        ("lab_a", "lab_b", "expected"),
        [
            # Sharma, Wu & Dalal (2005), Table 1, pairs 1, 2, 3, 7 and 17.
            ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
            ((50.0, 3.1571, -77.2803), (50.0, 0.0, -82.7485), 2.8615),
            ((50.0, 2.8361, -74.0200), (50.0, 0.0, -82.7485), 3.4412),
            ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
            ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
        ],
    )
    def test_ciede2000_reference_pairs(self, lab_a: tuple, lab_b: tuple, expected: float) -> None:
        assert float(cm.delta_e_2000(np.array(lab_a), np.array(lab_b))) == pytest.approx(expected, abs=1e-4)

    def test_reference_chart_white_and_grays(self) -> None:
        *_, reference = world()
        assert reference.white_xyz == pytest.approx([0.9504, 1.0, 1.0888], abs=2e-3)
        grays = reference.lab[list(cm_neutrals())]
        assert np.all(np.abs(grays[:, 1:]) < 7)  # the gray series is nearly neutral under D65 (white: b* 6.4)
        assert np.all(np.diff(grays[:, 0]) < 0)  # white → black
        assert 90 < grays[0, 0] < 100 and grays[-1, 0] < 25

    def test_perfect_image_has_zero_error_at_any_exposure(self) -> None:
        *_, reference = world()
        for exposure in (1.0, 3.7, 1e-3):
            result = cm.chart_delta_e(reference.xyz * exposure, np.eye(3), reference)
            assert result.mean == pytest.approx(0.0, abs=1e-9)
            assert result.scale == pytest.approx(1.0 / exposure)

    def test_camera_under_d65_is_close_and_the_cast_of_tungsten_is_not(self) -> None:
        *_, matrix, reference = world()
        d65 = cm.chart_delta_e(camera_means("D65"), matrix, reference)
        tungsten = cm.chart_delta_e(camera_means("A"), matrix, reference)
        # The 3×3 fit on the same chart under D65 is the floor of every ΔE (the camera is not
        # colorimetric): measured 1.81 mean for the NikonD100.
        assert d65.mean < 2.5 and d65.max < 8
        assert tungsten.mean > 5 * d65.mean

    def test_von_kries_removes_most_of_the_cast(self) -> None:
        _, camera, d65, matrix, reference = world()
        tungsten = datasets.illuminant("A", GRID)
        gains = cm.von_kries_gains(
            camera.values.T @ tungsten.to_unit("photons").values[:, 0],
            camera.values.T @ d65.to_unit("photons").values[:, 0],
        )
        balanced = cm.chart_delta_e(camera_means("A"), matrix, reference, white_balance=gains)
        raw = cm.chart_delta_e(camera_means("A"), matrix, reference)
        assert balanced.mean < 0.4 * raw.mean
        assert gains[1] == 1.0 and gains[2] > 2 * gains[0]  # tungsten lacks blue

    def test_shape_mismatch(self) -> None:
        *_, reference = world()
        with pytest.raises(SpectralDataError, match="one RGB triple per reference patch"):
            cm.chart_delta_e(np.ones((23, 3)), np.eye(3), reference)


def cm_neutrals() -> tuple[int, ...]:
    return (3, 7, 11, 15, 19, 23)


class TestWhiteBalance:
    def test_gains_map_white_to_white(self) -> None:
        ambient, target = np.array([3.0, 2.0, 0.5]), np.array([1.0, 1.1, 1.2])
        gains = cm.von_kries_gains(ambient, target)
        balanced = ambient * gains
        assert balanced / balanced[1] == pytest.approx(target / target[1])

    def test_mosaic_balance_equals_rgb_balance(self) -> None:
        rgb = np.random.default_rng(1).uniform(1, 2, (6, 8, 3))
        gains = np.array([2.0, 1.0, 0.5])
        for cfa in ("RGGB", "GBRG"):
            assert cm.von_kries_balance(mosaic(rgb, cfa), gains, cfa) == pytest.approx(
                mosaic(cm.von_kries_balance(rgb, gains), cfa)
            )
        with pytest.raises(SpectralDataError, match="cfa"):
            cm.von_kries_balance(rgb[..., 0], gains)

    def test_rejects_non_positive_whites(self) -> None:
        with pytest.raises(SpectralDataError, match="von Kries"):
            cm.von_kries_gains(np.array([1.0, 0.0, 1.0]), np.ones(3))


class TestNoise:
    def noisy_gray(self, sigma: tuple[float, float, float], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(seed)
        labels = np.zeros((40, 40), dtype=int)
        labels[:, 20:] = 1
        image = np.empty((40, 40, 3))
        for channel, level in enumerate((100.0, 200.0, 150.0)):
            image[..., channel] = level + rng.normal(0, sigma[channel], (40, 40))
        return image, labels

    def test_snr_is_mean_over_std_and_gain_invariant(self) -> None:
        image, labels = self.noisy_gray((10.0, 10.0, 30.0))
        snr = cm.channel_snr(image, labels, [0, 1])
        assert snr[:, 0] == pytest.approx(10.0, rel=0.1)
        assert snr[:, 1] == pytest.approx(20.0, rel=0.1)
        assert snr[:, 2] == pytest.approx(5.0, rel=0.1)
        balanced = cm.von_kries_balance(image, np.array([4.0, 1.0, 0.25]))
        assert cm.channel_snr(balanced, labels, [0, 1]) == pytest.approx(snr)

    def test_chroma_noise_grows_with_noise_and_with_amplified_channels(self) -> None:
        *_, reference = world()
        n = 2
        ref = cm.ReferenceChart(reference.xyz[[3, 7]], reference.lab[[3, 7]], reference.white_xyz, "D65")
        quiet, labels = self.noisy_gray((0.5, 0.5, 0.5))
        loud, _ = self.noisy_gray((5.0, 5.0, 5.0))
        srgb_to_xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
        noise_quiet = cm.chroma_noise(quiet, labels, [0, 1], srgb_to_xyz, ref, n)
        noise_loud = cm.chroma_noise(loud, labels, [0, 1], srgb_to_xyz, ref, n)
        assert np.all(noise_loud > 5 * noise_quiet)
        # A weak red channel brought up by von Kries brings its noise up with it.
        weak_red = quiet.copy()
        weak_red[..., 0] = quiet[..., 0] / 8 + np.random.default_rng(2).normal(0, 0.5, quiet.shape[:2])
        balanced = cm.chroma_noise(
            weak_red, labels, [0, 1], srgb_to_xyz, ref, n, white_balance=np.array([8.0, 1.0, 1.0])
        )
        assert np.all(balanced > 3 * noise_quiet)


class TestRendering:
    def test_bilinear_keeps_samples_and_is_exact_on_flat_channels(self) -> None:
        rgb = np.ones((8, 10, 3)) * np.array([3.0, 5.0, 7.0])
        for cfa in ("RGGB", "BGGR", "GRBG", "GBRG"):
            raw = mosaic(rgb, cfa)
            full = demosaic_bilinear(raw, cfa)
            assert full == pytest.approx(rgb)
            assert mosaic(full, cfa) == pytest.approx(raw)

    def test_bilinear_is_exact_on_linear_ramps_inside(self) -> None:
        rows, columns = np.mgrid[0:12, 0:12].astype(float)
        rgb = np.stack([rows + columns, 2 * rows - columns + 30, 0.5 * columns + 4], axis=-1)
        full = demosaic_bilinear(mosaic(rgb, "BGGR"), "BGGR")
        assert full[1:-1, 1:-1] == pytest.approx(rgb[1:-1, 1:-1])
        assert demosaic_superpixel(mosaic(rgb, "BGGR"), "BGGR").shape == (6, 6, 3)

    def test_superpixel_matches_bilinear_on_smooth_images(self) -> None:
        rgb = np.ones((8, 8, 3)) * np.array([1.0, 2.0, 3.0])
        assert demosaic_superpixel(mosaic(rgb, "RGGB"), "RGGB") == pytest.approx(
            demosaic_bilinear(mosaic(rgb, "RGGB"), "RGGB")[::2, ::2]
        )

    def test_xyz_of_a_perfect_white_is_the_white_point(self) -> None:
        chart, _, d65, *_ = world()
        white = chart.replace(values=np.ones((GRID.size, 1)), names=("white",))
        assert reflectances_to_xyz(white, d65)[0] == pytest.approx(
            reflectances_to_xyz(white, d65.to_unit("photons"))[0]
        )
        assert reflectances_to_xyz(white, d65)[0][1] == pytest.approx(1.0)

    def test_preview_white_balance_neutralises_a_gray_under_tungsten(self) -> None:
        _, camera, d65, matrix, _ = world()
        tungsten_white = camera.values.T @ datasets.illuminant("A", GRID).to_unit("photons").values[:, 0]
        gains = cm.von_kries_gains(tungsten_white, camera.values.T @ d65.to_unit("photons").values[:, 0])
        image = np.ones((2, 2, 3)) * tungsten_white
        cast = srgb_preview(image, matrix, white_value=float((tungsten_white @ matrix.T)[1]) * 1.2)
        balanced = srgb_preview(
            image, matrix, white_value=float((tungsten_white * gains @ matrix.T)[1]) * 1.2, white_balance=gains
        )
        assert int(cast[0, 0, 0]) - int(cast[0, 0, 2]) > 60  # orange
        assert abs(int(balanced[0, 0, 0]) - int(balanced[0, 0, 2])) <= 3  # gray
        with pytest.raises(SpectralDataError, match="white balance gains"):
            srgb_preview(image, matrix, white_balance=np.array([1.0, -1.0, 1.0]))
