"""The GenICam camera's options on the command line (``run``, ``capture``: ``hw`` and ``aravis-fake`` rigs).

``--trigger-line``, ``--strobe-line``, ``--gain``/``--gain-raw``, ``--roi``, ``--binning`` and repeatable
``--feature NAME=VALUE`` become one :class:`~acquisition.devices.aravis.camera_features.CameraOptions`; what they
mean and how they are checked is :mod:`acquisition.devices.aravis.camera_features` (the gain:
:mod:`acquisition.devices.aravis.gain`).
"""

from __future__ import annotations

import argparse

from msflash.acquisition.devices.aravis.camera_features import CameraOptions, parse_binning, parse_feature, parse_roi
from msflash.acquisition.devices.aravis.gain import parse_gain_db, parse_gain_raw

OPTION_NAMES = ("--trigger-line", "--strobe-line", "--gain", "--gain-raw", "--roi", "--binning", "--feature")
"""The options this module adds (all describe a GenICam camera)."""

FAKE_RIG_OPTIONS = ("--gain", "--gain-raw", "--feature")
"""Those the ``aravis-fake`` rig takes too (its ROI is the scene's, its lines are emulated)."""


def add_camera_options(group: argparse._ArgumentGroup) -> None:
    """Add the camera options to ``group`` (the hardware rig's)."""
    group.add_argument(
        "--trigger-line",
        default=None,
        metavar="LINE",
        help="camera TriggerSource the booth's trigger wire is on, for --sync booth (default: the "
        "camera profile's, else Line0)",
    )
    group.add_argument(
        "--strobe-line",
        default=None,
        metavar="LINE",
        help="camera output line driven by ExposureActive, for --sync camera (default: the camera "
        "profile's, else Line1)",
    )
    gain = group.add_mutually_exclusive_group()
    gain.add_argument(
        "--gain",
        type=parse_gain_db,
        default=None,
        metavar="DB",
        help="analogue gain in dB for every frame, e.g. 6 or 6dB: SFNC Gain, or GainRaw where the camera's "
        "profile gives its dB scale; checked against the camera's range before any frame "
        "(also on --rig aravis-fake)",
    )
    gain.add_argument(
        "--gain-raw",
        type=parse_gain_raw,
        default=None,
        metavar="N",
        help="analogue gain in the camera's own units, written as given to GainRaw (else its gain feature): "
        "for cameras whose GainRaw has no known dB scale; frames then record gain 1 "
        "(`msflash devices --features ID` shows the range)",
    )
    group.add_argument(
        "--roi", type=parse_roi, default=None, metavar="X,Y,W,H", help="region of interest in pixels (after binning)"
    )
    group.add_argument(
        "--binning",
        type=parse_binning,
        default=None,
        metavar="N|HxV",
        help="binning factors (BinningHorizontal, BinningVertical), e.g. 2 or 2x1",
    )
    group.add_argument(
        "--feature",
        type=parse_feature,
        action="append",
        default=None,
        metavar="NAME=VALUE",
        help="set any GenICam feature after binning and ROI, read back (repeatable); "
        "`msflash devices --features ID` lists them",
    )


def camera_options_from_args(args: argparse.Namespace) -> CameraOptions:
    """The options :func:`add_camera_options` parsed."""
    return CameraOptions(
        trigger_line=args.trigger_line,
        strobe_line=args.strobe_line,
        gain_db=args.gain.value if args.gain is not None else None,
        gain_raw=args.gain_raw.value if args.gain_raw is not None else None,
        roi=args.roi,
        binning=args.binning,
        features=tuple(args.feature or ()),
    )


def given_camera_options(args: argparse.Namespace) -> list[str]:
    """The camera options given on the command line, by name (they need a hardware rig)."""
    return [name for name in OPTION_NAMES if getattr(args, name[2:].replace("-", "_")) is not None]
