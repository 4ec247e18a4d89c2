"""Option groups that several commands share (the commands themselves never import one another)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from msflash.acquisition.app.cli_common import positive_int, user_number, whole
from msflash.acquisition.devices.sim_default import MONO, SIM_DEFAULT_CFA
from msflash.acquisition.session import analysis
from msflash.acquisition.session.rig import SimWorldOptions
from msflash.processing.ambient import AMBIENT_METHODS
from msflash.processing.user_numbers import plain_whole_number

TARGET_HELP = (
    "complementary target illuminant: a name (D65, A, FL2…), or a file: a table wavelength_nm,value or a "
    "spectrometer export of the light"
)
"""The help of every ``--target`` (what :func:`target_value` takes)."""


def target_value(text: str) -> str:
    """argparse type of ``--target``: a file (a table or a spectrometer export) or an illuminant name, both checked
    now (a file's coverage of the sequence's grid when it is used).

    A mistyped name is refused before a rig opens or a frame is captured, naming ``--target`` and the
    names it was probably meant to be.
    """
    from msflash.acquisition.session.sequence_spectra import is_target_file, target_file_spectrum
    from msflash.processing.errors import SpectralDataError

    if is_target_file(text):
        try:  # read now, so that a missing or dark file is refused before the rig meters or captures
            target_file_spectrum(text)
        except (ValueError, OSError) as err:  # every bad-input error of msflash is a ValueError
            # argparse names the option itself ("argument --target: …"): the error's own prefix is dropped
            raise argparse.ArgumentTypeError(str(err).removeprefix("--target ")) from None
        return text
    from msflash.processing import datasets
    from msflash.processing.spectra import DEFAULT_GRID

    try:
        datasets.illuminant(text, DEFAULT_GRID, outside="zero")
    except SpectralDataError as err:
        raise argparse.ArgumentTypeError(
            f"{err}; or a file: a table (wavelength_nm, value) or a spectrometer export of the light"
        ) from None
    return text


def setting_type(name: str, parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """argparse type of the estimate setting ``name``: the text ``parse``-d, then the setting's one rule
    (:data:`acquisition.session.one_sequence.SETTING_RULES`, which the Python API applies too), argparse naming
    the option."""

    def value_of(text: str) -> Any:
        from msflash.acquisition.session.one_sequence import SETTING_RULES

        # argparse.ArgumentTypeError: argparse prints its message; for a ValueError (UsageError is one)
        # it prints "invalid value_of value: '-1'" instead, naming this function and not what is expected.
        try:
            value = parse(text)
        except ValueError:
            value = None
        rule = SETTING_RULES[name]
        if not rule.accepts(value):
            raise argparse.ArgumentTypeError(rule.refusal(f"'{text}'"))
        return value

    return value_of


alpha_value = setting_type("alpha", lambda text: text if text == "auto" else user_number(text))
"""argparse type of ``--alpha``: a finite number ≥ 0, or ``auto``."""
bin_value = setting_type("bin_factor", plain_whole_number)
"""argparse type of ``--bin``: a whole number ≥ 1."""
tiles_value = setting_type("tiles", plain_whole_number)
"""argparse type of ``--tiles``: a whole number ≥ 1."""


SOLVER_CONSTRAINTS = {
    "tikhonov": "least squares with a squared roughness penalty; the spectrum I·w kept ≥ 0, each weight free",
    "roughness": "least squares with the paper's (unsquared) roughness penalty; the spectrum I·w kept ≥ 0, each "
    "weight free",
    "nonneg": "least squares; the spectrum I·w kept ≥ 0, each weight free",
    "lstsq": "plain least squares; nothing constrained",
}
"""What each ``--solver`` constrains, as the help and the run report say it (processing/ambient.py; the paper's
eq. 6 asks only I·w ≥ 0, so a single LED's weight may be negative where its neighbours overlap it)."""


def add_estimation_options(parser: argparse.ArgumentParser) -> None:
    """The options every command that estimates the ambient shares."""
    parser.add_argument(
        "--solver",
        default="tikhonov",
        choices=sorted(AMBIENT_METHODS),
        help="ambient estimator; "
        + "; ".join(f"{name}: {words}" for name, words in SOLVER_CONSTRAINTS.items())
        + " (default tikhonov; a single LED's weight may be negative, as the paper's eq. 6 allows)",
    )
    parser.add_argument(
        "--alpha",
        default="auto",
        type=alpha_value,
        help="dimensionless roughness weight of tikhonov and roughness, or 'auto' (default): tikhonov takes "
        "the largest whose fit stays within the noise of the least-penalised one (the discrepancy principle; "
        "each tile of --method local its own), roughness 0.01; lstsq and nonneg have none",
    )
    parser.add_argument(
        "--bin",
        type=bin_value,
        default=analysis.DEFAULT_BIN_FACTOR,
        help=f"sum BIN×BIN blocks of each channel (of each CFA plane of a mosaic: 2·BIN × 2·BIN pixels) before "
        f"estimating (default {analysis.DEFAULT_BIN_FACTOR}; an odd BIN is taken one smaller, and BIN is halved, "
        f"not below 4, on frames too small for {analysis.BLOCKS_PER_SIDE} blocks a side; 1 = every pixel)",
    )


def layout_options(parser: argparse.ArgumentParser, patch_type: Callable[[str], int] = whole) -> None:
    """``--patch-px``, ``--border-px``, ``--margin-px``: a given chart layout, or none (detect the chart)."""
    parser.add_argument(
        "--patch-px",
        type=patch_type,
        default=None,
        help="patch side in pixels of a chart at the top left (sim rig 8); without it and "
        "--border-px the chart is detected in each sequence",
    )
    parser.add_argument(
        "--border-px",
        type=whole,
        default=None,
        help="gap between patches in pixels (sim rig 2; default 2 with --patch-px)",
    )
    parser.add_argument("--margin-px", type=whole, default=1, help="pixels ignored inside each patch edge")


def flash_bounds_option(parser: argparse.ArgumentParser) -> None:
    """``--bounds physical|nonnegative``: the flash weights' bounds (``evaluate``, ``colour-study``)."""
    parser.add_argument(
        "--bounds",
        default="physical",
        choices=("physical", "nonnegative"),
        help="flash weights in [0, 1] (physical, default: re-capturable) or ≥ 0 (computational)",
    )


def _scheduler(text: str) -> str:
    """argparse type of ``--scheduler``: a blank value was taken for the default, ``local``.

    >>> _scheduler("none")
    'none'
    """
    if not text.strip():
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected 'local', 'none' or a dask scheduler address (tcp://HOST:PORT)"
        )
    return text


def add_scheduler_options(parser: argparse.ArgumentParser, default: str | None = "local", what: str = "jobs") -> None:
    """``--scheduler local|none|ADDRESS`` and ``--workers N``: where ``what`` run (acquisition/session/dask_map.py)."""
    parser.add_argument(
        "--scheduler",
        type=_scheduler,
        default=default,
        metavar="local|none|ADDRESS",
        help=f"where the {what} run: 'local' (a dask cluster on this machine, 127.0.0.1 only; default), 'none' "
        "(one after another in this process) or the ADDRESS of a running dask scheduler (tcp://HOST:PORT, whose "
        "workers have msflash installed; refused after 10 s without an answer)",
    )
    parser.add_argument(
        "--workers", type=positive_int, default=None, help="worker processes of --scheduler local (default: CPUs)"
    )


def add_fake_camera_option(parser: argparse.ArgumentParser) -> None:
    """``--fake-camera MODEL``: the ``aravis-fake`` rig's camera model (how it names its gain)."""
    from msflash.acquisition.devices.aravis.fake_models import DEFAULT_FAKE_MODEL, FAKE_MODELS

    parser.add_argument(
        "--fake-camera",
        default=None,
        choices=tuple(FAKE_MODELS),
        help=f"--rig aravis-fake: the fake's camera model (default {DEFAULT_FAKE_MODEL}): "
        + "; ".join(f"{name}: {model.summary}" for name, model in FAKE_MODELS.items()),
    )


SIM_CFA_CHOICES = ("RGGB", "BGGR", "GRBG", "GBRG", "none", MONO)
"""``--cfa`` of the ``sim`` rig: a Bayer layout, ``none`` for RGB frames, or ``mono`` for a monochrome sensor."""
SIM_CFA_HELP = (
    f"the simulated camera's colour filter: a raw Bayer mosaic of this layout, 12-bit (default {SIM_DEFAULT_CFA}, "
    "as colour machine-vision cameras send), none for 12-bit RGB frames, or mono for a monochrome sensor "
    "(no filter: Mono12 frames, the camera's R+G+B as its one responsivity)"
)


def sim_cfa(value: str | None) -> str | None:
    """The ``sim`` rig's CFA for ``--cfa``: not given → :data:`SIM_DEFAULT_CFA`, ``none`` → None (RGB frames),
    ``mono`` as it is (a monochrome sensor).

    >>> sim_cfa(None), sim_cfa("none"), sim_cfa("BGGR"), sim_cfa("mono")
    ('RGGB', None, 'BGGR', 'mono')
    """
    if value is None:
        return SIM_DEFAULT_CFA
    return None if value == "none" else value


def simulated_world(args: argparse.Namespace) -> SimWorldOptions:
    """The simulated world's options (``--ambient``, ``--scene``, ``--sim-camera``, ``--leds``, …) for the
    ``sim`` and ``aravis-fake`` rigs: one reading for ``run``, ``capture`` and ``live``."""
    return SimWorldOptions(
        ambient=args.ambient,
        scene=args.scene,
        seed=args.seed,
        camera=args.sim_camera,
        n_leds=args.leds,
        led_spectra=args.led_spectra,
        flash_power=args.flash_power,
    )
