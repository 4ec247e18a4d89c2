"""The sensor model of the simulation and the Bayer layouts of raw mosaics.

Public objects
--------------
- :class:`SensorModel`: black and white level, bit depth, conversion gain, read noise, full well,
  colour filter array; :func:`machine_vision_sensor`, the ``sim`` rig's default.
- :func:`mosaic`, :data:`CFA_PATTERNS`, :func:`cfa_channel_map`: the Bayer layouts.

Frames are rendered through a sensor by :func:`processing.image_formation.render_frame`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msflash.processing.errors import SpectralDataError

CFA_PATTERNS: dict[str, tuple[tuple[int, int], tuple[int, int]]] = {
    "RGGB": ((0, 1), (1, 2)),
    "BGGR": ((2, 1), (1, 0)),
    "GRBG": ((1, 0), (2, 1)),
    "GBRG": ((1, 2), (0, 1)),
}
"""Channel index (0 = R, 1 = G, 2 = B) at ``(row % 2, column % 2)`` for each Bayer layout."""


# -- the sensor -------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorModel:
    """A linear sensor: electrons → (gain, conversion gain) → digital numbers above a black level."""

    black_level: float = 256.0
    """Digital value of no light."""
    white_level: float = 65535.0
    """Digital value at and above which a pixel is saturated; clipped pixels read exactly this."""
    bit_depth: int = 16
    """Bits per sample; ``white_level`` must fit."""
    electrons_per_dn: float = 0.5
    """Conversion gain at gain 1: electrons per digital number."""
    read_noise_e: float = 2.0
    """Standard deviation of the read noise, in electrons (referred to the input)."""
    full_well_e: float = 40000.0
    """Electrons a pixel holds; a fuller pixel is clipped and reads ``white_level``."""
    cfa: str | None = None
    """Bayer layout of a raw mosaic (RGGB, BGGR, GRBG, GBRG) or None for full RGB frames."""

    def __post_init__(self) -> None:
        if not 1 <= self.bit_depth <= 32:
            raise SpectralDataError(f"sensor model: bit_depth {self.bit_depth}; expected 1–32")
        if not 0 <= self.black_level < self.white_level <= 2**self.bit_depth - 1:
            raise SpectralDataError(
                f"sensor model: black_level {self.black_level}, white_level {self.white_level}; expected "
                f"0 ≤ black < white ≤ {2**self.bit_depth - 1} ({self.bit_depth} bits)"
            )
        for name in ("electrons_per_dn", "full_well_e"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise SpectralDataError(f"sensor model: {name} is {value}; expected a finite value > 0")
        if not (math.isfinite(self.read_noise_e) and self.read_noise_e >= 0):
            raise SpectralDataError(f"sensor model: read_noise_e is {self.read_noise_e}; expected ≥ 0")
        if self.cfa is not None and self.cfa not in CFA_PATTERNS:
            raise SpectralDataError(
                f"sensor model: cfa '{self.cfa}'; expected None or one of {', '.join(CFA_PATTERNS)}"
            )

    @property
    def dtype(self) -> np.dtype:
        """The smallest unsigned integer type holding ``bit_depth`` bits."""
        return np.dtype(np.uint8 if self.bit_depth <= 8 else np.uint16 if self.bit_depth <= 16 else np.uint32)

    def saturation_electrons(self, gain: float) -> float:
        """Electrons at which a pixel saturates at ``gain``: the full well or the top code, whichever first."""
        return min(self.full_well_e, (self.white_level - self.black_level) * self.electrons_per_dn / gain)


def machine_vision_sensor(cfa: str | None = "RGGB") -> SensorModel:
    """A colour machine-vision camera's sensor: a 12-bit raw Bayer mosaic (``cfa``; None for RGB frames).

    The figures of a large-pixel global-shutter CMOS sensor of the class industrial colour cameras carry
    (Sony IMX174-class, EMVA 1288 data sheets: about 32 ke⁻ saturation, 7 e⁻ temporal dark noise):
    30.8 ke⁻ at the white level (8 e⁻ a digital number over 3855 codes), 7 e⁻ read noise, 12 bits with the
    black pedestal at 240 — what the ``sim`` rig's camera delivers by default
    (:meth:`acquisition.devices.simulated_camera.SimulatedCamera.default`). Small-pixel sensors hold a
    third of that (IMX264-class, 10.5 ke⁻): docs/raw-frames.md has the demo with one.

    >>> sensor = machine_vision_sensor()
    >>> sensor.cfa, sensor.bit_depth, sensor.dtype.name, round(sensor.saturation_electrons(1.0))
    ('RGGB', 12, 'uint16', 30840)
    """
    return SensorModel(
        black_level=240.0,
        white_level=4095.0,
        bit_depth=12,
        electrons_per_dn=8.0,
        read_noise_e=7.0,
        full_well_e=32000.0,
        cfa=cfa,
    )


# -- Bayer mosaics ----------------------------------------------------------------------------
def cfa_channel_map(cfa: str, shape: tuple[int, int]) -> np.ndarray:
    """Channel index (0 R, 1 G, 2 B) of every pixel of a ``cfa`` mosaic, int array ``shape``.

    Examples
    --------
    >>> cfa_channel_map("BGGR", (2, 2)).tolist()
    [[2, 1], [1, 0]]
    """
    if cfa not in CFA_PATTERNS:
        raise SpectralDataError(f"cfa '{cfa}': unknown layout; expected one of {', '.join(CFA_PATTERNS)}")
    tile = np.asarray(CFA_PATTERNS[cfa], dtype=np.int8)
    height, width = shape
    return np.tile(tile, ((height + 1) // 2, (width + 1) // 2))[:height, :width]


def mosaic(rgb: np.ndarray, cfa: str) -> np.ndarray:
    """Sample an (H, W, 3) image through a Bayer filter: (H, W), one channel per pixel.

    Examples
    --------
    >>> rgb = np.zeros((2, 2, 3)); rgb[..., 0], rgb[..., 1], rgb[..., 2] = 1, 2, 3
    >>> mosaic(rgb, "RGGB").tolist()
    [[1.0, 2.0], [2.0, 3.0]]
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise SpectralDataError(f"mosaic: image has shape {rgb.shape}; expected (H, W, 3)")
    channels = cfa_channel_map(cfa, rgb.shape[:2])
    return np.take_along_axis(rgb, channels[..., None].astype(np.intp), axis=2)[..., 0]
