"""The memory a reader may spend decoding, checked before it is spent (issue 32, item 2).

Every frame reader asks :func:`check_decode` with the bytes a file's header declares its pixels decode to
(width × height × channels × sample size) before decoding it, and a reader that holds several frames at
once (:func:`acquisition.session.analysis.load_frame_stack`) asks with their sum. Past the budget the read is
refused with a :class:`~acquisition.errors.RecordingError` (exit 2) naming the file, the size and the
budget, instead of a ``MemoryError`` (or the kernel's OOM killer) half-way through: a small file may
inflate to gigabytes (a decompression bomb).

The budget is ``--memory-budget`` (:func:`set_memory_budget`), else :data:`DEFAULT_SHARE` of the memory
available now: the kernel's ``MemAvailable`` and, under an address-space limit (``RLIMIT_AS``), what the
limit leaves above the process's present size, whichever is smaller.
"""

from __future__ import annotations

import re
import resource

from msflash.acquisition.errors import RecordingError, UsageError

DEFAULT_SHARE = 0.25
"""Share of the available memory one read may decode when no budget is given: the decoded pixels, their
working copies (block sums, linearised floats) and the statistics share what is available."""

_budget: int | None = None

_UNITS = {"": 1, "b": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}


def parse_size(text: str) -> int:
    """Bytes of a size such as ``800000000``, ``512M``, ``2G``, ``1.5GiB`` (powers of 1024).

    >>> parse_size("2G"), parse_size("512MiB"), parse_size("1000")
    (2147483648, 536870912, 1000)
    """
    match = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]+)?)\s*([kmgtKMGT]?)(?:i?[bB])?\s*", text)
    if match is None or float(match.group(1)) <= 0:
        raise UsageError(f"--memory-budget '{text}': expected a positive size such as 800M, 2G or 1500000000")
    return int(float(match.group(1)) * _UNITS[match.group(2).lower()])


def set_memory_budget(budget: int | None) -> None:
    """Use ``budget`` bytes for every read from now on (None: the default, from the memory available)."""
    global _budget
    _budget = budget


def available_memory() -> int:
    """Bytes this process may still allocate: ``MemAvailable``, or less under ``RLIMIT_AS``."""
    available = 1 << 62
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit != resource.RLIM_INFINITY:
        size = 0
        try:
            with open("/proc/self/status") as status:
                size = next((int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:")), 0)
        except OSError:
            pass
        available = min(available, max(0, limit - size))
    return available


def memory_budget() -> tuple[int, str]:
    """The budget in bytes and where it comes from (``--memory-budget``, or the memory available)."""
    if _budget is not None:
        return _budget, "--memory-budget"
    return int(available_memory() * DEFAULT_SHARE), f"{DEFAULT_SHARE:.0%} of the memory available"


def size_text(nbytes: float) -> str:
    """A size for people: ``864 MiB``, ``1.5 GiB``.

    >>> size_text(864 * 2**20), size_text(1.5 * 2**30), size_text(512)
    ('864 MiB', '1.5 GiB', '512 B')
    """
    for unit, scale in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} B"


def check_decode(where: str, nbytes: int, what: str) -> None:
    """Refuse decoding ``nbytes`` (``what``: how they come about) past the budget, naming ``where``.

    Raises
    ------
    RecordingError
        ``where: decoding WHAT needs SIZE, above the memory budget of BUDGET (SOURCE); expected …``.
    """
    budget, source = memory_budget()
    if nbytes > budget:
        raise RecordingError(
            f"{where}: decoding {what} needs {size_text(nbytes)}, above the memory budget of {size_text(budget)} "
            f"({source}); expected frames that fit it (a small file that inflates this far is refused unread; "
            "give --memory-budget SIZE to allow more)"
        )
