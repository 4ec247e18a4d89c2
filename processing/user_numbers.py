"""What a number a user typed or wrote is: the one parser of every number msflash reads from a person.

Every numeric option, every number of a list option (``--weights 1,0,…``), and every number cell of a user's
file (spectral tables, spectrometer exports and their headers) is read by :func:`plain_number` or
:func:`plain_whole_number`. Python's ``float`` and ``int`` accept more than a person means by a number:

- ``1_0`` is 10 (underscores group digits in Python source): ``--weights=1_0,…`` read a ten;
- ``١٢`` and other Unicode digits (Arabic-Indic, Devanagari, full-width ``１２``) are 12;
- ``inf``, ``infinity``, ``nan`` (any case) are numbers; ``1e400`` is infinity;
- ``int("0x10", 0)`` is 16 (kept only where a camera's register values are meant, not here).

A user's number here is plain decimal or scientific ASCII: an optional sign, digits with at most one point (``1.``,
``.5``), an optional exponent (``3e-4``, ``1E+002``), finite. Blanks around it are separators, as in a CSV cell
``400, 0.5``: they are dropped; anything else is refused with :class:`NotANumber` (a ``ValueError``), which each
caller turns into its one line naming the option, file, line or field. Decimal commas are the caller's to turn into
points where its format makes them unambiguous (:mod:`calibration.spectrometer`).
"""

from __future__ import annotations

import math
import re

_PLAIN = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_WHOLE = re.compile(r"[+-]?[0-9]+")
_BLANKS = " \t\r\n"
MAX_DIGITS = 300
"""Whole numbers of more digits are refused (beyond any count or size msflash takes; Python refuses 4300+)."""

EXPECTED_NUMBER = "a number such as 1.5, -2 or 3e-4 (ASCII digits, a point, an optional exponent)"
"""What :func:`plain_number` accepts, in the words its refusals use."""
EXPECTED_WHOLE_NUMBER = "a whole number such as 3 (ASCII digits)"
"""What :func:`plain_whole_number` accepts."""


class NotANumber(ValueError):
    """A text that is no plain number; the message quotes it and says what is expected."""


def _shown(text: str) -> str:
    return repr(text if len(text) <= 40 else text[:37] + "...")


def plain_number(text: str) -> float:
    """The finite number ``text`` writes in plain decimal or scientific ASCII (blanks around it dropped).

    Examples
    --------
    >>> plain_number("1.5"), plain_number(" -2 "), plain_number("3e-4"), plain_number(".5"), plain_number("1.")
    (1.5, -2.0, 0.0003, 0.5, 1.0)
    >>> plain_number("1_0")
    Traceback (most recent call last):
    ...
    msflash.processing.user_numbers.NotANumber: '1_0': expected a number such as 1.5, -2 or 3e-4 (ASCII digits, a point, an optional exponent)

    Raises
    ------
    NotANumber
        Underscores, non-ASCII digits, ``inf``/``nan``, hexadecimal, a decimal comma, an overflow (``1e400``).
    """
    stripped = text.strip(_BLANKS)
    if not _PLAIN.fullmatch(stripped) or len(stripped) > MAX_DIGITS + 10:
        raise NotANumber(f"{_shown(text)}: expected {EXPECTED_NUMBER}")
    value = float(stripped)
    if not math.isfinite(value):
        raise NotANumber(f"{_shown(text)}: expected a finite number (it overflows a double)")
    return value


def plain_whole_number(text: str) -> int:
    """The whole number ``text`` writes in ASCII digits with an optional sign (blanks around it dropped).

    Examples
    --------
    >>> plain_whole_number("42"), plain_whole_number(" -3 ")
    (42, -3)
    >>> plain_whole_number("١٢")
    Traceback (most recent call last):
    ...
    msflash.processing.user_numbers.NotANumber: '١٢': expected a whole number such as 3 (ASCII digits)

    Raises
    ------
    NotANumber
        Anything else: ``1.0``, ``1e3``, ``1_000``, ``0x10``, Unicode digits, more than :data:`MAX_DIGITS` digits.
    """
    stripped = text.strip(_BLANKS)
    if not _WHOLE.fullmatch(stripped) or len(stripped) > MAX_DIGITS + 1:
        raise NotANumber(f"{_shown(text)}: expected {EXPECTED_WHOLE_NUMBER}")
    return int(stripped)


_NON_FINITE = {"inf": math.inf, "infinity": math.inf, "nan": math.nan}


def number_or_non_finite(text: str) -> float:
    """:func:`plain_number`, except that a text naming a non-finite value (``inf``, ``-Infinity``, ``NaN``) or
    overflowing (``1e400``) is that value: for a caller whose refusal then says "expected a finite number", which
    tells the user more than "expected a number" would.

    >>> number_or_non_finite("2"), number_or_non_finite("-inf"), number_or_non_finite("1e400")
    (2.0, -inf, inf)

    Raises
    ------
    NotANumber
        Anything else :func:`plain_number` refuses (``1_0``, ``١٢``, ``0x10``).
    """
    stripped = text.strip(_BLANKS)
    named = _NON_FINITE.get(stripped.lstrip("+-").lower())
    if named is not None:
        return -named if stripped.startswith("-") else named
    if _PLAIN.fullmatch(stripped):
        return float(stripped)
    raise NotANumber(f"{_shown(text)}: expected {EXPECTED_NUMBER}")


def written_as_number(text: str) -> bool:
    """Whether ``text`` is written as a plain number, finite or not (``1e400`` is; ``inf``, ``1_0`` are not).

    >>> written_as_number("1e400"), written_as_number("inf")
    (True, False)
    """
    return _PLAIN.fullmatch(text.strip(_BLANKS)) is not None
