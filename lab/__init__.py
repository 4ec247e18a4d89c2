"""The lab: studies and benchmarks of msflash, outside the product (issue 31 item 4).

``msflash.lab`` imports the product (``msflash.acquisition``, ``msflash.processing``,
``msflash.calibration``, ``msflash.led_controller``) and is never imported by it: an import-linter
contract in ``pyproject.toml`` says so. The command line reaches its commands (``msflash study``,
``local-study``, ``colour-study``, ``bench``) by module name from its lazy command table
(:data:`msflash.acquisition.app.cli.COMMANDS`), only when one of them is run; a build without
this package lists none of them.

- ``study/``: the paper's simulation studies (Table 1, Figs. 5–7) and issue 9's (failure, Pareto,
  local estimation, block agreement), run serially or on dask (the ``study`` extra);
- ``cli_study``, ``cli_local``, ``cli_colour_study``: their commands (``cli_support``: what they share);
- ``bench/`` and ``cli_bench``: ``msflash bench``, speed as ratios measured interleaved in one run.
- ``progress``: how a study reports how far it got; ``wiring``: draws ``docs/booth-wiring.svg``
  from the firmware's pin table; ``text_booth_emulator``: the plain-text booth on a pty.

Their measurements live in ``docs/`` (``docs/study-*.md``, ``docs/speed.md``, …).
"""

from msflash.one_copy import one_copy

one_copy(__name__)  # "import lab" from the repository root: a one-line ImportError naming msflash.…
