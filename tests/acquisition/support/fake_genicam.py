"""The GenICam XML the in-process Aravis ``Fake`` camera loads: the tests choose it, msflash never does."""

from __future__ import annotations

import os

from msflash.acquisition.devices.aravis.discovery import FAKE_SFNC_XML, _builtin_fake_xml_path
from msflash.acquisition.devices.aravis.gi_typelib import Aravis


def use_fake_genicam(path: str | os.PathLike[str] | None = FAKE_SFNC_XML) -> None:
    """Make the in-process ``Fake`` interface camera load ``path`` as its GenICam XML.

    Takes effect for fake cameras opened afterwards (Aravis reads the file when the fake device
    is created). ``None`` restores the fake's built-in description.
    """
    builtin = _builtin_fake_xml_path()
    Aravis.set_fake_camera_genicam_filename(str(path) if path is not None else builtin)
