"""msflash: processing."""

from msflash.one_copy import one_copy

one_copy(__name__)  # "import processing" from the repository root: a one-line ImportError naming msflash.…
