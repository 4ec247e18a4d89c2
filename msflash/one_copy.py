"""One copy of each module: the product folders refuse their bare names (issue 31 item 6; tests/test_one_copy.py).

A module of its own that imports nothing, so that the folders can call it without depending on the
public face in ``msflash/__init__.py``.
"""

__all__ = ["one_copy"]


def one_copy(name: str) -> None:
    """Refuse a product folder imported under its bare name (``import processing`` from the repository root).

    The folders are msflash's subpackages (``msflash/processing`` links to ``processing/``); imported as
    ``processing`` they would load a second copy of the code, whose classes differ from msflash's
    (``processing.spectra.Spectra`` is not ``msflash.processing.spectra.Spectra``). Each folder's
    ``__init__`` calls this with its ``__name__``.

    >>> one_copy("msflash.processing")
    >>> one_copy("processing")
    Traceback (most recent call last):
    ImportError: 'processing' is msflash's folder: import msflash.processing (under its bare name it would be a second copy of msflash)
    """
    if not name.startswith("msflash."):
        raise ImportError(
            f"{name!r} is msflash's folder: import msflash.{name} (under its bare name it would be a second copy of msflash)",
            name=name,
        )
