"""``msflash live``: a browser page that frames, exposes, fires the sequence and shows the spectrum.

``server.py`` (the aiohttp application and its guard), ``state.py`` (what it remembers), ``preview.py``
(raw frame → JPEG, histogram, saturation), ``charts.py`` (a run's spectra as SVG), ``runs.py`` (run folders
and the files served from them), ``run_job.py`` (the fired sequence: ``msflash run``'s route into a run
folder) and ``static/`` (the page; ``msflash bench --part live`` measures its preview path from the lab,
``msflash.lab.bench.live``). The stream itself is :mod:`acquisition.session.live`. docs/architecture.md §5.4.
"""
