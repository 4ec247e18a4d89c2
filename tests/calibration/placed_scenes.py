"""A chart photographed anywhere in a frame: the chart-detection tests' scenes (a test twin)."""

from __future__ import annotations

import math

import numpy as np

from msflash.processing.errors import SpectralDataError
from msflash.processing.scenes import Scene, chart_scene  # noqa: F401  (chart_scene: the doctest)


def placed_scene(
    scene: Scene,
    shape: tuple[int, int],
    centre_yx: tuple[float, float] | None = None,
    angle_deg: float = 0.0,
    scale: float = 1.0,
    background_reflectance: float = 0.2,
) -> Scene:
    """``scene`` photographed on a flat background: scaled, rotated and placed anywhere in a frame.

    Each pixel of the new frame shows the surface under its centre (nearest neighbour), so a rotated
    chart has the jagged edges of a real sampled one; shading and the specular mask move with it.

    Parameters
    ----------
    scene
        The scene to place (typically :func:`chart_scene`).
    shape
        Size (H, W) of the new frame.
    centre_yx
        Where the scene's centre lands (row, column; pixel centres are integers); default the
        frame's centre.
    angle_deg
        Rotation, counter-clockwise as displayed (rows grow downwards).
    scale
        Pixels of the new frame per pixel of ``scene``.
    background_reflectance
        The flat surface, appended last and named ``"background"``, shown outside the scene.

    Returns
    -------
    Scene
        Surfaces of ``scene`` then ``"background"``.

    Examples
    --------
    >>> chart = chart_scene("macbeth", patch_px=8)  # 42 × 62 pixels, centre (20.5, 30.5)
    >>> placed = placed_scene(chart, (60, 80), centre_yx=(29.5, 39.5))
    >>> bool(np.array_equal(placed.labels[9:51, 9:71], chart.labels)), placed.reflectances.names[-1]
    (True, 'background')
    """
    height, width = int(shape[0]), int(shape[1])
    if height < 1 or width < 1 or not (math.isfinite(scale) and scale > 0) or not math.isfinite(angle_deg):
        raise SpectralDataError(
            f"placed_scene: shape {shape}, scale {scale}, angle {angle_deg}; expected a positive "
            "shape and scale and a finite angle"
        )
    centre = ((height - 1) / 2, (width - 1) / 2) if centre_yx is None else centre_yx
    source_centre = ((scene.shape[0] - 1) / 2, (scene.shape[1] - 1) / 2)
    rows, columns = np.mgrid[0:height, 0:width].astype(float)
    dy, dx = rows - centre[0], columns - centre[1]
    angle = math.radians(angle_deg)
    cos, sin = math.cos(angle), math.sin(angle)
    # Inverse map: undo the rotation (counter-clockwise as displayed: y points down) and the scale.
    source_x = (cos * dx - sin * dy) / scale + source_centre[1]
    source_y = (sin * dx + cos * dy) / scale + source_centre[0]
    row_index, column_index = np.rint(source_y).astype(np.int64), np.rint(source_x).astype(np.int64)
    inside = (row_index >= 0) & (row_index < scene.shape[0]) & (column_index >= 0) & (column_index < scene.shape[1])
    row_index, column_index = np.where(inside, row_index, 0), np.where(inside, column_index, 0)
    background = scene.reflectances.count
    labels = np.where(inside, scene.labels[row_index, column_index], background).astype(np.int32)
    shading = None if scene.shading is None else np.where(inside, scene.shading[row_index, column_index], 1.0)
    specular = None if scene.specular is None else inside & scene.specular[row_index, column_index]
    grid_size = scene.reflectances.grid.size
    surfaces = scene.reflectances.replace(
        values=np.hstack([scene.reflectances.values, np.full((grid_size, 1), float(background_reflectance))]),
        names=scene.reflectances.names + ("background",),
    )
    return Scene(surfaces, labels, shading=shading, specular=specular, specular_gain=scene.specular_gain)
