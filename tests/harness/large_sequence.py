"""A large raw sequence for memory measurements: the sim rig's capture enlarged by whole 2 × 2 cells of its mosaic.

``python -m tests.harness.large_sequence OUT [--width 4096] [--height 3000] [--seed 3]`` captures the sim rig's
sequence (``msflash capture --rig sim``: 106 × 112 RGGB, an ambient and 7 LED frames), repeats each 2 × 2 cell of
every frame to ``width × height`` (nearest cell, so the mosaic stays an RGGB mosaic), adds fresh read noise (σ 4
counts, so neighbouring copies differ) and writes the frames with the project's own writer
(:class:`~acquisition.sequence.writer.SequenceWriter`) to ``OUT``. A 4096 × 3000 frame is 24.6 MB in 16 bits: the
ambient and LED frames together are 197 MB. Used by docs/measurements.md (a reference patch from the stream).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from msflash.acquisition.app.cli import main as msflash_main
from msflash.acquisition.sequence.reader import read_sequence
from tests.helpers import rewrite_sequence

READ_NOISE = 4.0
"""Read noise added to every enlarged pixel, in counts."""


def enlarged(mosaic: np.ndarray, height: int, width: int, rng: np.random.Generator, white: float) -> np.ndarray:
    """``mosaic`` (H, W) with each 2 × 2 cell repeated to ``height × width`` (nearest cell), plus read noise."""
    cells_y, cells_x = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    rows = (np.arange(height // 2) * cells_y) // (height // 2)
    columns = (np.arange(width // 2) * cells_x) // (width // 2)
    cell_rows = (2 * rows[:, None] + np.arange(2)[None, :]).reshape(-1)
    cell_columns = (2 * columns[:, None] + np.arange(2)[None, :]).reshape(-1)
    big = mosaic[np.ix_(cell_rows, cell_columns)].astype(np.float32)
    big += rng.normal(0.0, READ_NOISE, size=big.shape).astype(np.float32)
    return np.clip(np.rint(big), 0, white).astype(np.uint16)


def write_large_sequence(out: Path, width: int = 4096, height: int = 3000, seed: int = 3) -> Path:
    """The sim rig's sequence enlarged to ``width × height`` (even), written to ``out`` (module notes)."""
    with tempfile.TemporaryDirectory() as scratch:
        captured = Path(scratch) / "capture"
        status = msflash_main(["capture", "--rig", "sim", "--seed", str(seed), "--out", str(captured)])
        if status != 0:
            raise SystemExit(status)
        rng = np.random.default_rng(seed)
        white = read_sequence(captured / "sequence").camera.white_level
        rewrite_sequence(
            captured / "sequence", out, lambda _index, _role, pixels: enlarged(pixels, height, width, rng, white)
        )
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--width", type=int, default=4096)
    parser.add_argument("--height", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=3)
    options = parser.parse_args()
    print(write_large_sequence(options.out, options.width - options.width % 2, options.height - options.height % 2))
