"""Names a user types: the one "did you mean" of msflash.

Public objects
--------------
- :func:`close_names`: the accepted names nearest to a mistyped one.
- :func:`unknown_name`: the one line saying a name is unknown, what it was probably meant to be,
  and what is accepted.

Every refusal of a name a user typed — ``--ambient``, ``--sim-camera``, ``--scene``, ``--leds``,
``--rig``, ``--feature``, ``--to``/``--export`` formats, ``--solver``, ``--model``, ``--chart``,
``--target``, a study, a subcommand, any option with fixed choices (``acquisition/app/cli.py``) —
is written by :func:`unknown_name`, so they all read alike: the suggestion first, and the full list
only when it is short or nothing is close (a list of 80 light names is no help to someone who
typed ``tungstn``).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

LIST_AT_MOST = 40
"""With a suggestion, the accepted names are all listed only if there are at most this many (else the first 8)."""
CUTOFF = 0.6
"""``difflib`` similarity (0…1) below which a name is not suggested."""


def close_names(given: str, accepted: Iterable[str], count: int = 3) -> list[str]:
    """The accepted names nearest to ``given``, best first: any that ``given`` starts, then by ``difflib`` ratio.

    Case is ignored.

    Examples
    --------
    >>> close_names("tungstn", ["tungsten", "fluorescent", "daylight"])
    ['tungsten']
    >>> close_names("FLUO", ["tungsten", "fluorescent"])
    ['fluorescent']
    >>> close_names("xyz", ["tungsten"])
    []
    """
    names = list(dict.fromkeys(str(name) for name in accepted))
    by_lower: dict[str, str] = {}
    for name in names:
        by_lower.setdefault(name.lower(), name)
    wanted = str(given).lower()
    starts = [name for name in names if wanted and name.lower().startswith(wanted) and name.lower() != wanted]
    similar = [by_lower[n] for n in difflib.get_close_matches(wanted, list(by_lower), n=count, cutoff=CUTOFF)]
    return list(dict.fromkeys(starts[:1] + similar))[:count]


def unknown_name(what: str, given: object, accepted: Iterable[object], also: str = "") -> str:
    """``<what> '<given>': unknown; did you mean 'x'? expected one of …`` — one line.

    Parameters
    ----------
    what
        Where the name came from (``--ambient``, ``light``, ``study``).
    accepted
        The names accepted (strings or numbers, as typed).
    also
        What else is accepted besides the names (``"blackbody:<kelvin>"``, ``"a CSV file"``), said last.

    Examples
    --------
    >>> unknown_name("--solver", "tikonov", ["lstsq", "nonneg", "roughness", "tikhonov"])
    "--solver 'tikonov': unknown; did you mean 'tikhonov'? expected one of lstsq, nonneg, roughness, tikhonov"
    >>> unknown_name("light", "tungstn", [f"n{i}" for i in range(40)] + ["tungsten"], "blackbody:<kelvin>")
    "light 'tungstn': unknown; did you mean 'tungsten'? expected one of n0, n1, n2, n3, n4, n5, n6, n7, … (41 names) or blackbody:<kelvin>"
    """
    names = [str(name) for name in accepted]
    suggestions = close_names(str(given), names)
    line = f"{what} {str(given)!r}: unknown"
    if suggestions:
        line += "; did you mean " + " or ".join(repr(name) for name in suggestions) + "?"
        listed = ", ".join(names) if len(names) <= LIST_AT_MOST else ", ".join(names[:8]) + f", … ({len(names)} names)"
    else:
        listed = ", ".join(names)
    line += f"{' ' if suggestions else '; '}expected one of {listed}"
    return line + (f" or {also}" if also else "")
