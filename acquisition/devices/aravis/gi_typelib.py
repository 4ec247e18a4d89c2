"""The Aravis 0.8 GObject typelib: the one place msflash imports ``gi``.

Every module of this folder takes ``Aravis`` and ``GLib`` from here; importing it without the
typelib raises one :class:`ImportError` naming what to install.
"""

from __future__ import annotations

import threading

try:
    import gi

    gi.require_version("Aravis", "0.8")
    from gi.repository import Aravis, GLib  # noqa: E402
except (ImportError, ValueError) as _err:  # ValueError: gi present but typelib Aravis-0.8 missing
    raise ImportError(
        "msflash.acquisition.devices.aravis.camera: the Aravis 0.8 GObject typelib is not available "
        f"({_err}); expected PyGObject and the Debian package gir1.2-aravis-0.8 — run setup.sh"
    ) from _err

aravis_lock = threading.RLock()
"""Aravis's interface list and device list are process globals."""

__all__ = ["Aravis", "GLib", "aravis_lock"]
