"""Parsing a JSON document a user's file holds, so that hostile input is refused naming the field.

Public objects
--------------
- :data:`MAX_NESTING`: the deepest nesting accepted.
- :func:`parse_json_document`: text to plain Python values, or an error naming the file and field.

Python's ``json`` reads ``NaN``, ``Infinity`` and ``1e999`` (as an infinite float), raises a plain
``ValueError`` for an integer of more than 4300 digits and a ``RecursionError`` for deep nesting;
none of them names a field, and the last two escape a reader that catches only
``JSONDecodeError``. Here every number is checked while it is parsed (a non-finite or huge one
becomes a marker), and one walk without recursion then names the first marker's field, or the
first field nested deeper than :data:`MAX_NESTING`.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from typing import Any

MAX_NESTING = 100
"""Objects and lists nested deeper than this are refused (calibration files need 4)."""
MAX_DIGITS = 300
"""Integers with more digits than this are refused (a float holds up to 309)."""


class _Unreadable:
    """A number that is no finite float, kept until its field can be named."""

    def __init__(self, text: str) -> None:
        self.text = text if len(text) <= 20 else f"an integer of {len(text.lstrip('-'))} digits"


def _integer(text: str) -> int | _Unreadable:
    return _Unreadable(text) if len(text.lstrip("-")) > MAX_DIGITS else int(text)


def _convertible_integer(text: str) -> int | _Unreadable:
    limit = sys.get_int_max_str_digits()  # beyond it Python refuses to convert (and to write back)
    return _Unreadable(text) if limit and len(text.lstrip("-")) > limit else int(text)


def _float(text: str) -> float | _Unreadable:
    value = float(text)
    return value if math.isfinite(value) else _Unreadable(text)


def _field(where: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


def parse_json_document(
    text: str, source: str, error: Callable[[str], Exception], *, finite_numbers: bool = True
) -> Any:
    """The document in ``text``; ``error(message)`` is raised for anything that is not plain finite JSON.

    Parameters
    ----------
    error
        The exception type (or factory) the caller raises for bad input.
    finite_numbers
        Refuse every non-finite or huge number wherever it is (the default). ``False`` keeps
        ``NaN``, infinities and integers Python can convert as values, for a format that keeps
        other tools' unknown keys without interpreting them (``sequence.json``): its reader then
        checks each field it reads.

    Raises
    ------
    Exception
        ``error(message)``, the message naming ``source`` and, where there is one, the field:
        invalid JSON (with its line), a key twice in one object, ``NaN``/``Infinity``/an overflowing
        float, an integer of more than :data:`MAX_DIGITS` digits, nesting deeper than :data:`MAX_NESTING`.

    Examples
    --------
    >>> parse_json_document('{"a": [1, 2.5]}', "x.json", ValueError)
    {'a': [1, 2.5]}
    >>> parse_json_document('{"a": {"b": [0, NaN]}}', "x.json", ValueError)
    Traceback (most recent call last):
    ...
    ValueError: x.json: field 'a.b[1]' is NaN; expected a finite number
    """

    def unique(pairs: list[tuple[str, Any]]) -> dict:
        result: dict = {}
        for key, value in pairs:
            if key in result:
                raise error(f"{source}: key {key[:40]!r} appears twice in one object; expected unique keys")
            result[key] = value
        return result

    try:
        if finite_numbers:
            document = json.loads(
                text, object_pairs_hook=unique, parse_int=_integer, parse_float=_float, parse_constant=_Unreadable
            )
        else:
            document = json.loads(text, object_pairs_hook=unique, parse_int=_convertible_integer)
    except json.JSONDecodeError as err:
        raise error(f"{source}: line {err.lineno} column {err.colno}: {err.msg}; expected valid JSON") from None
    except RecursionError:
        raise error(
            f"{source}: objects or lists nested too deep to read; expected at most {MAX_NESTING} levels"
        ) from None
    stack: list[tuple[Any, str, int]] = [(document, "", 0)]
    while stack:
        value, where, depth = stack.pop()
        if isinstance(value, _Unreadable):
            raise error(f"{source}: field '{where or '(top level)'}' is {value.text}; expected a finite number")
        if isinstance(value, dict | list):
            if depth >= MAX_NESTING:
                raise error(
                    f"{source}: field '{where}' is nested {depth + 1} levels deep; expected at most {MAX_NESTING}"
                )
            items = value.items() if isinstance(value, dict) else enumerate(value)
            stack.extend((item, _field(where, key), depth + 1) for key, item in reversed(list(items)))
    return document
