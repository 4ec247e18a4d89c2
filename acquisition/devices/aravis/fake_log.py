"""The Aravis fake's per-frame complaint about pixel formats its pattern generator does not fill.

The fake streams frames of any ``PixelFormat`` its GenICam XML lists, but its pattern generator
(``arv_fake_camera_diagonal_ramp`` in Aravis 0.8.26) fills only Mono8/16, Bayer8 and RGB8 and logs
``g_critical("Unsupported pixel format")`` (no log domain) for every other frame. The
``aravis-fake`` rig replaces every frame's pixels with a rendered scene
(:class:`acquisition.devices.wired_fake.WiredFakeCamera`), so that line — one per frame on stderr —
says nothing; :func:`mute_unfilled_format_warning` drops exactly it while the rig is open and
passes every other critical message on to GLib's default handler.
"""

from __future__ import annotations

from collections.abc import Callable

import gi

gi.require_version("GLib", "2.0")
from gi.repository import GLib  # noqa: E402

UNFILLED_FORMAT_MESSAGE = "Unsupported pixel format"
"""What the fake logs for each frame it cannot fill."""


def mute_unfilled_format_warning() -> Callable[[], None]:
    """Drop the fake's :data:`UNFILLED_FORMAT_MESSAGE` lines until the returned function is called (once, when
    the fake is released)."""

    def handler(domain: str | None, level: GLib.LogLevelFlags, message: str, *_data: object) -> None:
        if message != UNFILLED_FORMAT_MESSAGE:
            GLib.log_default_handler(domain, level, message, None)

    handler_id = GLib.log_set_handler(None, GLib.LogLevelFlags.LEVEL_CRITICAL, handler, None)

    def remove() -> None:
        GLib.log_remove_handler("", handler_id)  # GLib files the NULL domain under ""; PyGObject refuses None here

    return remove
