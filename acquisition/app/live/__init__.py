"""``msflash live``: a browser page that frames, exposes, fires the sequence and shows the spectrum.

The page is ``static/``; the stream itself is :mod:`acquisition.session.live`. docs/architecture.md §5.4.
"""
