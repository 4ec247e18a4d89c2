"""Chart detection (calibration/chart_detection.py): the sim rig's Macbeth chart anywhere in the frame.

Sequences are recorded through the whole sim rig (``msflash capture``) with the chart placed by
:func:`tests.calibration.placed_scenes.placed_scene`; the truth is the placed scene's own label image.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app import cli
from msflash.acquisition.devices.simulated_camera import SimulatedCamera
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.rigs import sim as rig_module
from msflash.calibration.chart_detection import detect_chart, detect_in_sequence
from msflash.calibration.chart_grid import MACBETH_GRID, ChartDetectionError, ChartGrid
from msflash.calibration.chart_placement import ColourFrames
from msflash.processing import datasets
from msflash.processing.scenes import Scene, chart_scene, uniform_scene
from tests.calibration.placed_scenes import placed_scene
from tests.helpers import GRID, SAMPLES_DIR, ambient, leds_photons, linear_frames

N_PATCHES = MACBETH_GRID[0] * MACBETH_GRID[1]


def _chart(patch_px: int = 8) -> Scene:
    return chart_scene("macbeth", patch_px=patch_px, specular_strip_px=4)


def _record(
    out: Path, scene: Scene | None, ambient_name: str = "tungsten", seed: int = 1, cfa: str | None = None
) -> Path:
    """A sim rig capture of ``scene`` (None: the rig's own chart at the top left); ``cfa`` None is the rig's
    default camera (a raw RGGB mosaic), ``"none"`` RGB frames."""
    default = SimulatedCamera.default.__func__

    class PlacedWorld(SimulatedCamera):
        @classmethod
        def default(cls, **options):
            if scene is not None:
                options["scene"] = scene
            return default(cls, **options)

    argv = [
        "capture",
        "--rig",
        "sim",
        "--scene",
        "macbeth",
        "--ambient",
        ambient_name,
        "--seed",
        str(seed),
        "--out",
        str(out),
    ]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rig_module, "SimulatedCamera", PlacedWorld)
        assert cli.main(argv + (["--cfa", cfa] if cfa else [])) == 0
    return out / "sequence"


# Offsets (odd and fractional), scales, small rotations, upside down; RGB and RGGB.
PLACEMENTS = {
    "offset-rgb": (dict(shape=(90, 120), centre_yx=(50.3, 61.7)), "none"),
    "rotated-scaled-rgb": (dict(shape=(110, 150), centre_yx=(60.0, 68.0), angle_deg=6.0, scale=1.5), "none"),
    "rotated-rggb": (dict(shape=(100, 130), centre_yx=(47.0, 70.0), angle_deg=-5.0, scale=1.3), "RGGB"),
    "upside-down-rggb": (dict(shape=(90, 120), centre_yx=(44.5, 57.5), angle_deg=183.0), "RGGB"),
}


@pytest.fixture(scope="module")
def placed(tmp_path_factory) -> dict[str, tuple[Path, Scene]]:
    root = tmp_path_factory.mktemp("placed")
    recorded = {}
    for seed, (name, (placement, cfa)) in enumerate(PLACEMENTS.items()):
        scene = placed_scene(_chart(), **placement)
        recorded[name] = (_record(root / name, scene, seed=seed + 1, cfa=cfa), scene)
    return recorded


def _true_centres(scene: Scene) -> np.ndarray:
    """Centroids (x, y) of the scene's chart patches, chart order."""
    centres = []
    for k in range(N_PATCHES):
        y, x = np.nonzero(scene.labels == k)
        centres.append([x.mean(), y.mean()])
    return np.array(centres)


def _patch_centres(grid: ChartGrid) -> np.ndarray:
    """Centres (x, y) of the detected grid's patches in chart order (column by column), shape (rows·columns, 2)."""
    k = np.arange(grid.rows * grid.columns)
    lattice = np.column_stack([k // grid.rows, k % grid.rows]).astype(float)
    return lattice @ np.column_stack([grid.column_step_xy, grid.row_step_xy]).T + np.asarray(grid.origin_xy)


def test_patch_centres_follow_the_lattice_column_by_column() -> None:
    grid = ChartGrid(4, 6, (5.5, 5.5), (10.0, 0.0), (0.0, 10.0), (0.8, 0.8), 0.004, 0.44, 24)
    assert _patch_centres(grid)[1].tolist() == [5.5, 15.5]


def _detect(path: Path):
    sequence = read_sequence(path)
    return sequence, detect_in_sequence(
        sequence, datasets.macbeth().resample(sequence.grid, outside="edge"), *MACBETH_GRID
    )


def _assert_labels_inside_true_patches(labels: np.ndarray, scene: Scene, min_pixels: int) -> None:
    labelled = labels >= 0
    assert np.array_equal(labels[labelled], scene.labels[labelled])  # every labelled pixel is that patch
    assert np.bincount(labels[labelled], minlength=N_PATCHES).min() >= min_pixels


@pytest.mark.parametrize("name", list(PLACEMENTS))
def test_detection_agrees_with_the_placed_chart_within_a_pixel(placed, name):
    path, scene = placed[name]
    sequence, grid = _detect(path)
    error = np.hypot(*(_patch_centres(grid) - _true_centres(scene)).T)
    assert error.max() <= 1.0, f"{name}: patch centres off by up to {error.max():.2f} px"
    placement = PLACEMENTS[name][0]
    scale, angle = placement.get("scale", 1.0), placement.get("angle_deg", 0.0)
    assert grid.pitch_px == pytest.approx((10 * scale, 10 * scale), abs=0.3)  # 8-px patches, 2-px border
    assert (grid.rotation_deg - angle + 180) % 360 - 180 == pytest.approx(0, abs=1.0)
    assert grid.corner == ("bottom-right" if abs(angle) > 90 else "top-left") and not grid.mirrored
    labels = grid.labels(sequence.load_frame(0).shape[:2])
    _assert_labels_inside_true_patches(labels, scene, min_pixels=9)
    assert grid.misfit < grid.runner_up_misfit / 10


def test_the_sim_rigs_own_layout_is_found_exactly(tmp_path):
    path = _record(tmp_path / "default", None)
    sequence, grid = _detect(path)
    scene = _chart()
    assert np.allclose(_patch_centres(grid), _true_centres(scene), atol=0.05)
    from msflash.acquisition.session.chart_layout import chart_layout

    given = chart_layout(sequence.load_frame(0).shape[:2], "macbeth", 8, 2, 1).labels
    assert np.array_equal(grid.labels(given.shape), given)  # the same label map as --patch-px 8 --border-px 2


def test_a_mirrored_chart_in_noise_free_frames():
    scene = placed_scene(_chart(), (80, 100), centre_yx=(41.0, 47.0), angle_deg=3.0)
    mirrored = Scene(scene.reflectances.resample(GRID), scene.labels[:, ::-1], specular=scene.specular[:, ::-1])
    ambient_frame, led_frames, spec = linear_frames(ambient("daylight"), scene=mirrored)
    lights = leds_photons().replace(values=leds_photons().values @ spec.led_levels.T)
    colour = ColourFrames(0, tuple(range(1, len(led_frames) + 1)), lights)
    chart = datasets.macbeth().resample(lights.grid, outside="edge")
    grid = detect_chart(
        [ambient_frame, *led_frames], np.zeros(mirrored.shape, dtype=bool), None, colour, chart, *MACBETH_GRID
    )
    assert grid.mirrored and grid.corner == "top-right"
    assert np.abs(_patch_centres(grid) - _true_centres(mirrored)).max() <= 1.0
    _assert_labels_inside_true_patches(grid.labels(mirrored.shape), mirrored, min_pixels=16)


def _detect_synthetic(sigma_px: float = 0.0, shading_low: float = 1.0, where: str = "frames"):
    """Detection on noisy linear frames of a 12-px chart (2-px border) at 4°: blurred by a Gaussian of
    ``sigma_px``, lit with a left-to-right falloff to ``shading_low``; LED signals ~30 % of the
    ambient, noise 0.2 % of full scale. Returns the scene and the grid."""
    from scipy.ndimage import gaussian_filter

    placed = placed_scene(chart_scene("macbeth", patch_px=12), (100, 130), centre_yx=(50.0, 63.0), angle_deg=4.0)
    columns = np.arange(placed.shape[1], dtype=float)
    falloff = np.clip(1 - (1 - shading_low) * (columns - 20) / 90, shading_low, 1)
    scene = Scene(placed.reflectances.resample(GRID), placed.labels, shading=np.tile(falloff, (placed.shape[0], 1)))
    ambient_frame, led_frames, spec = linear_frames(ambient("tungsten"), scene=scene)
    led_frames = [ambient_frame + 100 * (frame - ambient_frame) for frame in led_frames]
    rng = np.random.default_rng(7)
    frames = [
        gaussian_filter(frame, (sigma_px, sigma_px, 0)) + rng.normal(0, 2e-3 * frame.max(), frame.shape)
        for frame in [ambient_frame, *led_frames]
    ]
    lights = leds_photons().replace(values=leds_photons().values @ spec.led_levels.T)
    colour = ColourFrames(0, tuple(range(1, len(frames))), lights)
    chart = datasets.macbeth().resample(GRID, outside="edge")
    return scene, detect_chart(frames, np.zeros(scene.shape, dtype=bool), None, colour, chart, *MACBETH_GRID, where)


@pytest.mark.parametrize(("sigma_px", "found"), [(1.0, True), (3.0, False)])
def test_a_blurred_chart_is_found_until_its_patches_have_no_flat_centre(sigma_px, found):
    if found:
        scene, grid = _detect_synthetic(sigma_px)
        assert np.abs(_patch_centres(grid) - _true_centres(scene)).max() <= 1.0
    else:
        with pytest.raises(ChartDetectionError, match="blurred: no 4×6 chart found: fewer than 18 uniform"):
            _detect_synthetic(sigma_px, where="blurred")


def test_uneven_light_across_the_chart():
    # Half the light at the chart's right edge: patches still uniform enough, colours still the chart's.
    scene, grid = _detect_synthetic(shading_low=0.5)
    assert np.abs(_patch_centres(grid) - _true_centres(scene)).max() <= 1.0
    assert grid.misfit < 0.1 < grid.runner_up_misfit


def _calibrate(sequences: list[Path], out: Path, capsys, *extra: str) -> dict:
    argv = [
        "calibrate",
        "camera",
        "--sequence",
        *map(str, sequences),
        "--light",
        "tungsten",
        "--light",
        "daylight",
        "--prior-exclude",
        "NikonD100",
        "--out",
        str(out),
        "--json",
        *extra,
    ]
    capsys.readouterr()
    assert cli.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_calibration_from_detected_layouts_matches_the_given_layout(tmp_path, capsys):
    default = [_record(tmp_path / "t", None, "tungsten", 1), _record(tmp_path / "d", None, "daylight", 2)]
    detected = _calibrate(default, tmp_path / "a", capsys)
    given = _calibrate(default, tmp_path / "b", capsys, "--patch-px", "8", "--border-px", "2")
    assert detected["rmse_vs_sequence_responsivity"] == pytest.approx(given["rmse_vs_sequence_responsivity"], abs=1e-9)
    assert [layout["detected"] for layout in detected["layouts"]] == [True, True]
    assert {key: given["layouts"][0][key] for key in ("detected", "patch_px", "border_px", "margin_px")} == {
        "detected": False,
        "patch_px": 8,
        "border_px": 2,
        "margin_px": 1,
    }
    # The chart moved between the two sequences (another place, scale and rotation) and one is a mosaic.
    moved = [
        _record(tmp_path / "mt", placed_scene(_chart(), (90, 120), centre_yx=(50.3, 61.7)), "tungsten", 1),
        _record(
            tmp_path / "md",
            placed_scene(_chart(), (100, 130), centre_yx=(47.0, 70.0), angle_deg=-5.0, scale=1.3),
            "daylight",
            2,
        ),
    ]
    payload = _calibrate(moved, tmp_path / "c", capsys)
    assert payload["rmse_vs_sequence_responsivity"] <= 0.05
    assert abs(payload["rmse_vs_sequence_responsivity"] - given["rmse_vs_sequence_responsivity"]) <= 0.01
    first, second = payload["layouts"]
    assert first["origin_xy"] == pytest.approx([36.5, 33.5], abs=0.5) and first["corner"] == "top-left"
    assert second["rotation_deg"] == pytest.approx(-5.0, abs=1.0) and second["pitch_px"] == pytest.approx(
        [13, 13], abs=0.3
    )


def test_evaluate_finds_the_chart_itself(placed, tmp_path, capsys):
    path, _ = placed["rotated-rggb"]
    capsys.readouterr()
    assert cli.main(["evaluate", str(path), "--chart", "macbeth", "--out", str(tmp_path / "ev"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["layout_parameters"]["detected"] and result["layout_parameters"]["corner"] == "top-left"
    assert "chart detected" in result["layout"]
    assert result["delta_e"]["ambient"]["mean"] > 0


def _two_charts() -> Scene:
    chart = _chart()
    return Scene(chart.reflectances, np.hstack([chart.labels, chart.labels]), specular=np.hstack([chart.specular] * 2))


@pytest.mark.parametrize(
    ("scene", "message"),
    [
        (lambda: uniform_scene(datasets.macbeth().select([6]), 60, 80), "no 4×6 chart found: fewer than 18 uniform"),
        (lambda: placed_scene(_chart(patch_px=1), (60, 80)), "no 4×6 chart found"),  # 1-pixel patches
        (lambda: placed_scene(_chart(patch_px=2), (60, 80)), "--margin-px 1 leaves nothing of the 2.0-pixel patches"),
        (_two_charts, "2 4×6 charts found"),
    ],
)
def test_no_single_chart_is_refused_naming_the_sequence_and_the_options(tmp_path, capsys, scene, message):
    path = _record(tmp_path / "scene", scene(), cfa="none")  # RGB frames: 2-pixel patches, a 1-pixel margin
    capsys.readouterr()
    argv = [
        "calibrate",
        "camera",
        "--sequence",
        str(path),
        "--prior-exclude",
        "NikonD100",
        "--out",
        str(tmp_path / "c"),
    ]
    assert cli.main(argv) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.startswith("msflash: error:") and message in error
    assert str(path) in error
    if "margin" not in message:
        assert "--patch-px/--border-px" in error
        with pytest.raises(ChartDetectionError, match=message):
            _detect(path)


@pytest.mark.skipif(not SAMPLES_DIR.exists(), reason="shared samples not present")
@pytest.mark.parametrize("sample", ["sample-rgb-tungsten", "sample-bayer-fluorescent-12bit"])
def test_the_shared_samples_show_no_macbeth_chart(sample):
    # Their scene is the Natural-100 set on an edge-to-edge grid: an 8×8 grid is found, no 4×6 window of it
    # has the Macbeth chart's colours.
    with pytest.raises(ChartDetectionError, match="a grid of 8×8 uniform patches whose colours .* do not match"):
        _detect(SAMPLES_DIR / sample)
