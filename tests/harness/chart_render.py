"""An independent render of chart sequences: the authors' Macbeth chart and LEDs, a camera msflash never saw.

Issue 29 item 5. The render shares nothing with msflash's simulator: the spectra are read here
with numpy from the shared data (``/work/shared/data``, or the copies msflash ships where they
are the same files), resampled with ``np.interp``, the daylight comes from colour-science and
tungsten is Planck's law at 2856 K (CIE A's definition); pixels are photons through the camera's
curves, a lens's falloff, Poisson shot noise, read noise, a black level and 16-bit quantisation,
and each sequence is written through the format-v1 writer (the file format is the contract).

Split: the **tuning** cameras (Point Grey Grasshopper2 14S5C; every choice of the light-field
model was made looking at it only) and the **held-out** ones (Aptina MT9M031, an industrial
sensor; Point Grey Grasshopper 50S5C; Nikon D2xs, which is not among msflash's 34 cameras at
all). The camera under test is always left out of the prior (``--prior-exclude``).

Run ``.venv/bin/python -m tests.harness.chart_render`` for the table in ``docs/calibration.md``.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
from msflash.acquisition.sequence.writer import SequenceWriter

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "data" if (ROOT.parent / "shared" / "data").exists() else Path("/work/shared/data")
AUTHORS_CHART = ROOT / "processing" / "data" / "paper" / "macbethChart_reflectance_380_1068_4nm.csv"
AUTHORS_LEDS = ROOT / "processing" / "data" / "paper" / "ximeaLights_energy_380_1068_4nm.csv"
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
TUNING = ("Point Grey Grasshopper2 14S5C",)
HELD_OUT = ("AptinaMT9M031", "Point Grey Grasshopper 50S5C", "NikonD2xsNikon50mm")
PRIOR_NAMES = {"AptinaMT9M031": "AptinaMT9M031", "NikonD2xsNikon50mm": None}
"""The camera's name among msflash's 34 (to leave it out of the prior); None: not among them."""


def _table(path: Path) -> tuple[np.ndarray, list[str], np.ndarray]:
    lines = [line for line in path.read_text().splitlines() if line and not line.startswith("#")]
    names = lines[0].split(",")[1:]
    rows = np.array(
        [[float(c) if c.strip().lower() != "nan" else np.nan for c in line.split(",")] for line in lines[1:]]
    )
    return rows[:, 0], names, rows[:, 1:]


def _on_grid(wavelengths: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(WAVELENGTHS, wavelengths, np.nan_to_num(v)) for v in values.T])


def camera(name: str) -> np.ndarray:
    """(31, 3) photon responsivities of ``name`` on 400–700/10, max 1."""
    if name.startswith("Point Grey"):
        w, names, values = _table(SHARED / "cameras" / "jiang2013" / "jiang2013_28cameras_400_720_10nm.csv")
        columns = [names.index(f"{name}|{c}") for c in "RGB"]
    else:
        w, names, values = _table(SHARED / "cameras" / "isetcam" / f"{name}.csv")
        columns = [0, 1, 2]
    curves = _on_grid(w, values[:, columns])
    return curves / curves.max()


def authors_chart() -> np.ndarray:
    w, _, values = _table(AUTHORS_CHART)
    return _on_grid(w, values)


def isetcam_chart_file() -> Path:
    return ROOT / "processing" / "data" / "reflectances" / "charts" / "macbethChart_24.csv"


def authors_leds() -> np.ndarray:
    w, _, values = _table(AUTHORS_LEDS)
    return _on_grid(w, values)


def tungsten() -> np.ndarray:
    """Planck at 2856 K (CIE illuminant A's definition), energy."""
    metres = WAVELENGTHS * 1e-9
    return 1.0 / (metres**5 * (np.exp(1.435e-2 / (metres * 2856.0)) - 1.0))


def daylight() -> np.ndarray:
    import colour

    sd = colour.SDS_ILLUMINANTS["D65"]
    return np.interp(WAVELENGTHS, sd.wavelengths, sd.values)


def photons(energy: np.ndarray) -> np.ndarray:
    return energy * WAVELENGTHS[:, None] if energy.ndim == 2 else energy * WAVELENGTHS


@dataclass(frozen=True)
class Scene:
    """Where the chart lies and how the light falls."""

    shape: tuple[int, int] = (270, 360)
    pitch_px: int = 52
    patch_px: int = 44
    origin_yx: tuple[int, int] = (33, 29)
    falloff: float = 0.0
    """Relative illumination lost at the frame's corners (0.12: an ordinary lens)."""
    rows: int = 4
    columns: int = 6
    """The chart's grid (the Macbeth chart's 4 × 6 unless a test prints its patches otherwise)."""

    def labels(self) -> np.ndarray:
        """Patch of each pixel (column by column), −1 on the border and background."""
        h, w = self.shape
        y, x = np.mgrid[0:h, 0:w]
        row, dy = np.divmod(y - self.origin_yx[0], self.pitch_px)
        column, dx = np.divmod(x - self.origin_yx[1], self.pitch_px)
        inside = (
            (row >= 0)
            & (row < self.rows)
            & (column >= 0)
            & (column < self.columns)
            & (dy < self.patch_px)
            & (dx < self.patch_px)
        )
        return np.where(inside, column * self.rows + row, -1)

    def gain(self) -> np.ndarray:
        """Relative illumination: a cos⁴-like falloff, ``1 − falloff · (r / r_corner)²``."""
        h, w = self.shape
        y, x = np.mgrid[0:h, 0:w]
        r2 = ((y - (h - 1) / 2) ** 2 + (x - (w - 1) / 2) ** 2) / (((h - 1) / 2) ** 2 + ((w - 1) / 2) ** 2)
        return 1.0 - self.falloff * r2


def render_sequence(
    out: Path, curves: np.ndarray, ambient: np.ndarray, ambient_name: str, scene: Scene, seed: int, model: str
) -> Path:
    """Write one chart sequence (ambient, then ambient + each LED) and return its folder."""
    rng = np.random.default_rng(seed)
    chart = authors_chart()
    leds = authors_leds()
    labels = scene.labels()
    surfaces = np.hstack([chart, np.full((WAVELENGTHS.size, 1), 0.04)])  # the chart's black border / background
    index = np.where(labels >= 0, labels, chart.shape[1])
    step = 10.0

    def radiance_rgb(light_energy: np.ndarray) -> np.ndarray:  # (surfaces, 3) per unit light
        return (surfaces * photons(light_energy)[:, None]).T @ curves * step

    leds = leds / leds.max()
    ambient = ambient / ambient.max()
    led_rgb = [radiance_rgb(leds[:, k]) for k in range(leds.shape[1])]
    ambient_rgb = radiance_rgb(ambient)
    # Powers: the white patch's largest channel at about the same signal under the ambient and the
    # brightest LED (one drive scale for all LEDs: their true ratios are kept).
    white = 3  # ISET order: patch 4 is white
    ambient_power = 1.0 / ambient_rgb[white].max()
    led_power = min(1.0 / rgb[white].max() for rgb in led_rgb)
    full_well, black, read_noise = 60000.0, 64.0, 4.0
    peak_electrons = 0.55 * full_well / 2  # ambient + the brightest LED stay below ~60 % of the range
    gain_map = scene.gain()

    def frame(rgb_per_surface: np.ndarray) -> np.ndarray:
        electrons = rgb_per_surface[index] * gain_map[..., None] * peak_electrons
        noisy = rng.poisson(np.maximum(electrons, 0)).astype(float) + rng.normal(0, read_noise, electrons.shape)
        return np.clip(np.rint(noisy + black), 0, 65535).astype(np.uint16)

    with SequenceWriter(
        out,
        wavelengths_nm=WAVELENGTHS,
        spectral_unit="energy",
        camera=SequenceCamera(
            model,
            None,
            "RGB16",
            None,
            black,
            65535.0,
            # recorded in the sequence's unit (energy): c_energy ∝ c_photons · λ
            {c: curves[:, i] * WAVELENGTHS / WAVELENGTHS.max() for i, c in enumerate("RGB")},
        ),
        leds=[SequenceLed(f"led{k}", leds[:, k] * led_power / ambient_power) for k in range(leds.shape[1])],
        extra={"render": {"ambient": ambient_name, "falloff": scene.falloff, "tool": "tests/harness/chart_render.py"}},
    ) as writer:
        base = ambient_rgb * ambient_power
        writer.add_frame(frame(base), "ambient", [0.0] * leds.shape[1], 10000.0)
        for k, rgb in enumerate(led_rgb):
            levels = [0.0] * leds.shape[1]
            levels[k] = 1.0
            writer.add_frame(frame(base + rgb * led_power), "led", levels, 10000.0)
    # The sequence's spectral unit is energy with photons-rendered pixels: the LED spd written is
    # relative energy and msflash converts to photons itself, as a real capture's would be.
    return out


def _run(argv: list[str]) -> tuple[int, dict | None, str]:
    from msflash.acquisition.app import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main(argv)
    return status, (json.loads(out.getvalue()) if status == 0 else None), err.getvalue()


def calibrate(
    folder: Path, camera_name: str, falloff: float, chart: str, flat: bool, seed: int = 0
) -> tuple[float | None, str]:
    """Render two sequences (tungsten, daylight) and run ``calibrate camera``; RMSE vs the truth or the refusal."""
    curves = camera(camera_name)
    scene = Scene(falloff=falloff)
    tag = f"{camera_name.replace(' ', '_')}-{falloff:g}-{seed}"
    sequences = []
    for offset, (light, name) in enumerate(((tungsten(), "A"), (daylight(), "D65"))):
        path = folder / f"{tag}-{name}"
        if not (path / "sequence.json").exists():
            render_sequence(path, curves, light, name, scene, seed * 10 + offset, camera_name)
        sequences.append(str(path))
    argv = ["calibrate", "camera", "--sequence", *sequences, "--light", "A", "--light", "D65"]
    prior_name = PRIOR_NAMES.get(camera_name, camera_name)
    if prior_name:
        argv += ["--prior-exclude", prior_name]
    if chart != "macbeth":
        argv += ["--chart", chart]
    if flat:
        argv.append("--flat-light")
    out = folder / f"cal-{tag}-{Path(chart).stem}-{'flat' if flat else 'field'}"
    status, payload, err = _run([*argv, "--out", str(out), "--json"])
    if status != 0:
        return None, err.strip().splitlines()[-1]
    assert payload is not None
    return truth_rmse(out, curves), ""


def truth_rmse(calibration: Path, curves: np.ndarray) -> float:
    """RMSE of the calibration's responsivities against the rendered camera's (photons, max-normalised)."""
    from msflash.calibration.camera_response import responsivity_rmse
    from msflash.calibration.files import load_calibration
    from msflash.processing.spectra import Spectra, WavelengthGrid

    estimate = load_calibration(calibration).camera_responsivities
    assert estimate is not None
    truth = Spectra(WavelengthGrid(400.0, 700.0, 10.0), curves, ("R", "G", "B"), kind="responsivity", unit="photons")
    return responsivity_rmse(estimate.resample(truth.grid, outside="zero"), truth)


def main() -> int:
    import tempfile

    with tempfile.TemporaryDirectory() as work:
        folder = Path(work)
        print("| split | camera | chart reference | falloff | flat light | fitted light field |")
        print("|---|---|---|---|---|---|")
        for split, names in (("tuning", TUNING), ("held out", HELD_OUT)):
            for name in names:
                for chart in ("macbeth", str(AUTHORS_CHART)):
                    for falloff in (0.0, 0.12):
                        cells = []
                        for flat in (True, False):
                            rmse, refusal = calibrate(folder, name, falloff, chart, flat)
                            cells.append(f"{rmse:.4f}" if rmse is not None else "refused: " + refusal[16:150])
                        label = "ISETCam (shipped)" if chart == "macbeth" else "authors'"
                        print(f"| {split} | {name} | {label} | {falloff:.0%} | {cells[0]} | {cells[1]} |")
                        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
