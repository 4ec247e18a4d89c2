"""Image formation (eq. 1–3) and the sensor model."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing import datasets, lights
from msflash.processing.errors import SpectralDataError
from msflash.processing.image_formation import (
    expected_response,
    exposure_for_peak,
    render_frame,
    surface_responses,
    total_illumination,
)
from msflash.processing.scenes import Scene, chart_scene, uniform_scene
from msflash.processing.sensor import CFA_PATTERNS, SensorModel, cfa_channel_map, mosaic
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

TOLERANCE = 1e-9


@pytest.fixture(scope="module")
def camera() -> Spectra:
    return datasets.isetcam_camera("NikonD100").resample(DEFAULT_GRID)


@pytest.fixture(scope="module")
def leds() -> Spectra:
    return datasets.paper_leds().resample(DEFAULT_GRID)


@pytest.fixture(scope="module")
def ambient() -> Spectra:
    return lights.ambient_spectrum("tungsten")


@pytest.fixture(scope="module")
def chart() -> Scene:
    scene = chart_scene("chart110", patch_px=4, border_px=1)
    shading = np.linspace(0.5, 1.0, scene.shape[1])[None, :] * np.ones(scene.shape)
    return Scene(scene.reflectances, scene.labels, shading=shading)


def gray(value: float) -> Spectra:
    return Spectra(DEFAULT_GRID, np.full(DEFAULT_GRID.size, value), ("gray",), kind="reflectance", unit="none")


class TestExpectedResponse:
    def test_matches_the_discretised_integral(self, camera: Spectra, ambient: Spectra) -> None:
        scene = chart_scene(datasets.macbeth().resample(DEFAULT_GRID), patch_px=3)
        response = expected_response(scene, ambient, camera, exposure_us=2.0, gain=3.0, scale=0.5)
        r = scene.reflectances.values[:, 5]
        i = ambient.to_unit("photons").values[:, 0]
        c = camera.values
        expected = 0.5 * 2.0 * 3.0 * (c * (r * i)[:, None]).sum(axis=0) * DEFAULT_GRID.step_nm
        pixel = tuple(np.argwhere(scene.labels == 5)[0])
        np.testing.assert_allclose(response[pixel], expected, rtol=TOLERANCE)

    def test_linear_in_the_illuminant(self, chart: Scene, camera: Spectra, ambient: Spectra, leds: Spectra) -> None:
        """Eq. 3: m(i_a + i_f) = m(i_a) + m(i_f), the basis of the flash-only difference images."""
        levels = [0.3, 0.0, 1.0, 0.2, 0.0, 0.7, 0.1]
        both = expected_response(chart, total_illumination(ambient, leds, levels), camera, 100.0)
        ambient_only = expected_response(chart, ambient, camera, 100.0)
        flash_only = expected_response(
            chart, total_illumination(ambient.replace(values=ambient.values * 0), leds, levels), camera, 100.0
        )
        np.testing.assert_allclose(both, ambient_only + flash_only, rtol=1e-12)
        per_led = sum(
            expected_response(
                chart,
                total_illumination(ambient.replace(values=ambient.values * 0), leds, np.eye(7)[k] * levels[k]),
                camera,
                100.0,
            )
            for k in range(7)
        )
        np.testing.assert_allclose(flash_only, per_led, rtol=1e-12)

    def test_linear_in_exposure_gain_and_scale(self, chart: Scene, camera: Spectra, ambient: Spectra) -> None:
        base = expected_response(chart, ambient, camera, 100.0)
        np.testing.assert_allclose(expected_response(chart, ambient, camera, 200.0), 2 * base, rtol=1e-12)
        np.testing.assert_allclose(
            expected_response(chart, ambient, camera, 100.0, gain=4.0, scale=0.5), 2 * base, rtol=1e-12
        )

    def test_units_are_converted_to_photons(self, chart: Scene, camera: Spectra, ambient: Spectra) -> None:
        in_energy = expected_response(chart, ambient, camera.to_unit("energy"), 10.0)
        in_photons = expected_response(chart, ambient.to_unit("photons"), camera, 10.0)
        np.testing.assert_allclose(in_energy, in_photons, rtol=1e-12)

    def test_grids_must_match(self, chart: Scene, camera: Spectra) -> None:
        coarse = datasets.illuminant("D65", WavelengthGrid(400, 700, 20))
        with pytest.raises(SpectralDataError, match="expected one grid"):
            expected_response(chart, coarse, camera, 10.0)

    def test_shading_and_specular(self, camera: Spectra, ambient: Spectra) -> None:
        labels = np.zeros((2, 3), dtype=int)
        shading = np.array([[1.0, 0.5, 0.0], [1.0, 1.0, 1.0]])
        specular = np.array([[False, False, False], [False, False, True]])
        scene = Scene(gray(0.2), labels, shading=shading, specular=specular, specular_gain=2.0)
        response = expected_response(scene, ambient, camera, 1.0)
        white = surface_responses(gray(1.0), ambient, camera)[0]
        np.testing.assert_allclose(response[0, 0], 0.2 * white, rtol=1e-12)
        np.testing.assert_allclose(response[0, 1], 0.1 * white, rtol=1e-12)
        np.testing.assert_allclose(response[0, 2], 0.0, atol=1e-12)
        np.testing.assert_allclose(response[1, 2], 2.2 * white, rtol=1e-12)


class TestScenes:
    def test_chart110_layout(self) -> None:
        scene = chart_scene(patch_px=5, border_px=2)
        assert scene.reflectances.count == 111 and scene.reflectances.names[-1] == "border"
        assert scene.shape == (10 * 5 + 11 * 2, 11 * 5 + 12 * 2)
        counts = np.bincount(scene.labels.ravel(), minlength=111)
        assert np.all(counts[:110] == 25)
        # the 10-step gray strip (patches 101–110) fills the last column, top to bottom
        gray_columns = {int(c) for k in range(100, 110) for c in np.argwhere(scene.labels == k)[:, 1]}
        assert min(gray_columns) > scene.shape[1] - 5 - 2 - 1
        assert scene.surface_mask("border").sum() == counts[110]

    def test_macbeth_layout_and_specular_strip(self) -> None:
        scene = chart_scene("macbeth", patch_px=4, border_px=1, specular_strip_px=3)
        assert scene.shape == (4 * 4 + 5 + 3, 6 * 4 + 7)
        assert scene.specular is not None and scene.specular.sum() == 3 * scene.shape[1]
        # ISET order: patch 4 (index 3) is white, at the bottom of the first column
        rows = np.argwhere(scene.labels == 3)[:, 0]
        assert rows.min() == 1 + 3 * 5

    @pytest.mark.parametrize(
        ("labels", "shading", "match"),
        [
            (np.array([[0, 1]]), None, "labels span 0…1; expected 0…0"),
            (np.zeros((2, 2), dtype=int), np.ones((3, 3)), "shading has shape"),
            (np.zeros((2, 2)), None, "expected a non-empty integer array"),
        ],
    )
    def test_bad_scenes(self, labels: np.ndarray, shading: np.ndarray | None, match: str) -> None:
        with pytest.raises(SpectralDataError, match=match):
            Scene(gray(0.5), labels, shading=shading)

    def test_arrays_are_frozen(self) -> None:
        scene = uniform_scene(gray(0.5), 2, 2)
        with pytest.raises(ValueError):
            scene.labels[0, 0] = 1


class TestSensor:
    sensor = SensorModel(
        black_level=100.0,
        white_level=4095.0,
        bit_depth=12,
        electrons_per_dn=0.5,
        read_noise_e=3.0,
        full_well_e=100000.0,
    )

    def electrons_scale(self, camera: Spectra, ambient: Spectra, electrons: float) -> float:
        """The scale giving ``electrons`` expected electrons in the green channel of a 50% gray at 1 µs."""
        return electrons / surface_responses(gray(0.5), ambient, camera)[0, 1]

    def test_noise_statistics_match_poisson_plus_read(self, camera: Spectra, ambient: Spectra) -> None:
        gain = 2.0
        scale = self.electrons_scale(camera, ambient, 400.0)
        scene = uniform_scene(gray(0.5), 256, 256)
        frame = render_frame(scene, ambient, camera, self.sensor, 1.0, gain, scale, rng=np.random.default_rng(7))
        assert frame.dtype == np.uint16 and frame.shape == (256, 256, 3)
        dn_per_e = gain / self.sensor.electrons_per_dn
        expected_e = expected_response(scene, ambient, camera, 1.0, 1.0, scale)[0, 0]
        for channel in range(3):
            values = frame[..., channel].astype(float)
            mean = self.sensor.black_level + dn_per_e * expected_e[channel]
            variance = dn_per_e**2 * (expected_e[channel] + self.sensor.read_noise_e**2) + 1 / 12
            assert values.mean() == pytest.approx(mean, rel=2e-3)
            assert values.var() == pytest.approx(variance, rel=0.04)

    def test_seeded_frames_repeat(self, chart: Scene, camera: Spectra, ambient: Spectra) -> None:
        a = render_frame(chart, ambient, camera, self.sensor, 10.0, rng=np.random.default_rng(3))
        b = render_frame(chart, ambient, camera, self.sensor, 10.0, rng=np.random.default_rng(3))
        np.testing.assert_array_equal(a, b)

    def test_black_level_in_the_dark(self, chart: Scene, camera: Spectra, ambient: Spectra) -> None:
        clean = render_frame(chart, ambient, camera, self.sensor, 0.0, noise=False)
        assert np.all(clean == 100)
        noisy = render_frame(chart, ambient, camera, self.sensor, 0.0, gain=1.0, rng=np.random.default_rng(1))
        assert noisy.mean() == pytest.approx(100.0, abs=0.05)
        assert noisy.std() == pytest.approx(3.0 / 0.5, rel=0.05)

    def test_saturation_at_white_level(self, chart: Scene, camera: Spectra, ambient: Spectra) -> None:
        exposure = exposure_for_peak(chart, ambient, camera, self.sensor, fraction=1.0)
        frame = render_frame(chart, ambient, camera, self.sensor, 5 * exposure, rng=np.random.default_rng(0))
        assert frame.max() == 4095
        expected = expected_response(chart, ambient, camera, 5 * exposure) / self.sensor.electrons_per_dn
        over = expected > 1.2 * (4095 - 100)  # well clear of the noise
        assert over.any() and np.all(frame[over] == 4095)

    def test_full_well_reads_white_level(self, camera: Spectra, ambient: Spectra) -> None:
        sensor = SensorModel(
            black_level=0, white_level=65535, bit_depth=16, electrons_per_dn=0.1, read_noise_e=0.0, full_well_e=1000.0
        )
        scene = uniform_scene(gray(0.5), 4, 4)
        scale = self.electrons_scale(camera, ambient, 5000.0)
        frame = render_frame(scene, ambient, camera, sensor, 1.0, 1.0, scale, rng=np.random.default_rng(0))
        assert np.all(frame[..., 1] == 65535)  # 5000 e⁻ in a 1000 e⁻ well: clipped, flagged as saturated

    def test_exposure_for_peak(self, camera: Spectra, ambient: Spectra) -> None:
        scene = chart_scene("macbeth", patch_px=3, specular_strip_px=2)
        scene = Scene(scene.reflectances.resample(DEFAULT_GRID), scene.labels, specular=scene.specular)
        exposure = exposure_for_peak(scene, ambient, camera, self.sensor, fraction=0.95)
        frame = render_frame(scene, ambient, camera, self.sensor, exposure, noise=False)
        diffuse = frame[~scene.specular]
        assert diffuse.max() == pytest.approx(100 + 0.95 * (4095 - 100), abs=1)
        assert np.all(frame[scene.specular].max(axis=-1) == 4095)  # the highlight saturates
        with pytest.raises(SpectralDataError, match="fraction"):
            exposure_for_peak(scene, ambient, camera, self.sensor, fraction=1.5)

    @pytest.mark.parametrize(
        "bad", [dict(white_level=5000.0), dict(black_level=5000.0), dict(cfa="RGBW"), dict(electrons_per_dn=0.0)]
    )
    def test_bad_sensor_models(self, bad: dict) -> None:
        fields = dict(black_level=100.0, white_level=4095.0, bit_depth=12) | bad
        with pytest.raises(SpectralDataError, match="sensor model"):
            SensorModel(**fields)


class TestMosaic:
    @pytest.mark.parametrize(
        ("cfa", "top_left"),
        [("RGGB", "RG/GB"), ("BGGR", "BG/GR"), ("GRBG", "GR/BG"), ("GBRG", "GB/RG")],
    )
    def test_layouts(self, cfa: str, top_left: str) -> None:
        rgb = np.zeros((4, 6, 3))
        for channel in range(3):
            rgb[..., channel] = 10 * (channel + 1)
        sampled = mosaic(rgb, cfa)
        letters = {10: "R", 20: "G", 30: "B"}
        quad = "".join(letters[int(v)] for v in sampled[:2, :2].ravel())
        assert quad[:2] + "/" + quad[2:] == top_left
        np.testing.assert_array_equal(sampled, np.tile(sampled[:2, :2], (2, 3)))  # 2×2 periodic
        assert np.count_nonzero(sampled == 20) == sampled.size // 2

    @pytest.mark.parametrize("cfa", sorted(CFA_PATTERNS))
    def test_rendered_mosaic(self, cfa: str, camera: Spectra, ambient: Spectra) -> None:
        sensor = SensorModel(black_level=0.0, white_level=65535.0, cfa=cfa)
        scene = uniform_scene(gray(0.5), 5, 7)
        frame = render_frame(scene, ambient, camera, sensor, 100.0, noise=False)
        rgb = render_frame(
            scene, ambient, camera, SensorModel(black_level=0.0, white_level=65535.0), 100.0, noise=False
        )
        assert frame.shape == (5, 7)
        np.testing.assert_array_equal(frame, mosaic(rgb, cfa))
        assert cfa_channel_map(cfa, (5, 7)).shape == (5, 7)

    def test_unknown_cfa(self) -> None:
        with pytest.raises(SpectralDataError, match="expected one of RGGB"):
            mosaic(np.zeros((2, 2, 3)), "XYZW")
