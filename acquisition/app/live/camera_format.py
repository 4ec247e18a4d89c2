"""ROI, binning and pixel format from the live page: the request a page sends, read as every user's JSON is, and
what the page is told the camera allows (``POST /api/camera-format``, the state's ``camera_format``).

The camera does the checking (:mod:`acquisition.devices.image_format`): here a body becomes a typed
:class:`~acquisition.devices.image_format.ImageFormatRequest`, or a one-line :class:`UsageError` naming the key
and what was expected.
"""

from __future__ import annotations

from typing import Any

from msflash.acquisition.devices.camera import CameraInfo
from msflash.acquisition.devices.image_format import ImageFormatControl, ImageFormatRequest
from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.live import LiveStream

KEYS = ("roi", "binning", "pixel_format")


def _whole_numbers(body: dict[str, Any], key: str, count: int, example: str) -> tuple[int, ...]:
    given = body[key]
    if (
        not isinstance(given, list)
        or len(given) != count
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in given)
    ):
        raise UsageError(f"{key} {str(given)[:60]}: expected {count} whole numbers, e.g. {example}")
    return tuple(int(v) for v in given)


def format_request(body: dict[str, Any]) -> ImageFormatRequest:
    """``{"roi": [x, y, w, h], "binning": [h, v], "pixel_format": "BayerRG8"}`` (any of them) as a request.

    Raises
    ------
    UsageError
        An unknown key, none of them, or a value of the wrong form.
    """
    unknown = sorted(set(body) - set(KEYS))
    if unknown or not any(key in body for key in KEYS):
        what = f"unknown key {unknown[0][:40]!r}" if unknown else "nothing to set"
        raise UsageError(f"camera format: {what}; expected some of {', '.join(KEYS)}")
    roi = binning = pixel_format = None
    if "roi" in body:
        x, y, w, h = _whole_numbers(body, "roi", 4, "[0, 0, 64, 48]")
        if min(x, y) < 0 or min(w, h) < 1:
            raise UsageError(f"roi {[x, y, w, h]}: expected offsets ≥ 0 and sizes ≥ 1")
        roi = (x, y, w, h)
    if "binning" in body:
        h_bin, v_bin = _whole_numbers(body, "binning", 2, "[2, 2]")
        if min(h_bin, v_bin) < 1:
            raise UsageError(f"binning {[h_bin, v_bin]}: expected factors ≥ 1")
        binning = (h_bin, v_bin)
    if "pixel_format" in body:
        if not isinstance(body["pixel_format"], str) or not body["pixel_format"]:
            raise UsageError(f"pixel_format {str(body['pixel_format'])[:40]}: expected a GenICam name, e.g. BayerRG8")
        pixel_format = body["pixel_format"]
    return ImageFormatRequest(roi, binning, pixel_format)


def camera_format_json(info: CameraInfo, stream: LiveStream) -> dict[str, Any]:
    """What the page shows and offers: the frame's size and format, the format in force and each feature's limits
    (read from the camera: call it on the rig thread)."""
    camera = stream.rig.camera
    limits = stream.image_limits()
    return {
        "summary": f"{info.pixel_format} · {info.width} × {info.height} px",
        "pixel_format": info.pixel_format,
        "width": info.width,
        "height": info.height,
        "format": camera.image_format.to_json() if isinstance(camera, ImageFormatControl) else None,
        "limits": limits.to_json() if limits is not None else None,
    }
