"""The hardware rig's camera options on the command line (``run``, ``capture``).

``--trigger-line``, ``--strobe-line``, ``--gain``, ``--roi``, ``--binning`` and repeatable
``--feature NAME=VALUE`` become one :class:`~acquisition.devices.aravis.camera_features.CameraOptions`; what they
mean and how they are checked is :mod:`acquisition.devices.aravis.camera_features`.
"""

from __future__ import annotations

import argparse

from msflash.acquisition.devices.aravis.camera_features import CameraOptions, parse_binning, parse_feature, parse_roi

OPTION_NAMES = ("--trigger-line", "--strobe-line", "--gain", "--roi", "--binning", "--feature")
"""The options this module adds (all describe a hardware rig's camera)."""


def _gain_db(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"'{text}': expected a gain in dB, e.g. 6")
    return value


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
    group.add_argument(
        "--gain",
        type=_gain_db,
        default=None,
        metavar="DB",
        help="analogue gain in dB for every frame (SFNC Gain; checked against the camera's range)",
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
        gain_db=args.gain,
        roi=args.roi,
        binning=args.binning,
        features=tuple(args.feature or ()),
    )


def given_camera_options(args: argparse.Namespace) -> list[str]:
    """The camera options given on the command line, by name (they need a hardware rig)."""
    return [name for name in OPTION_NAMES if getattr(args, name[2:].replace("-", "_")) is not None]
