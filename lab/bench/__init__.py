"""``msflash bench``'s parts: each module measures one part of msflash as ratios taken interleaved in one
run (``processing``, ``startup``, ``camera``, ``booth``, ``capture``, ``decode``, ``live``, ``many``,
``flash_energy``; ``ratios`` holds the shared timing helpers). Figures and targets: docs/speed.md."""
