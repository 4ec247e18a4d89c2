"""Results in other tools' formats: DNG, OME-TIFF, CSV and EXR (``msflash export``, ``run --export``).

The writers (:mod:`.dng`, :mod:`.ome_tiff`, :mod:`.spectra_csv`) take arrays and plain values and
know no sequence; :mod:`.exr_metadata` says what an EXR of a sequence carries;
:mod:`.sequence_export` reads a sequence, estimates its ambient through
:mod:`acquisition.session.analysis` (the one route) and calls them (docs/architecture.md §2.4).
"""
