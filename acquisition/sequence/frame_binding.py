"""Is a frame file the one its ``sequence.json`` entry says? What the file says about itself, against the entry.

Every frame msflash writes carries, in its own metadata, the entry it was written for: its index in
``frames``, its role, LED levels, exposure and gain (``msflash:*`` attributes, docs/architecture.md §6).
A digest (``frames[].sha256``) proves a file's bytes are those written, not that the entry naming it
is the one it was written for: swap ``file``, ``sha256`` and ``file_bytes`` between two entries and each
file is still intact while every number computed from them is silently wrong. Readers therefore
compare the two (:func:`binding_problem`, on every :meth:`Sequence.load_frame`), and ``msflash check``
names swapped, duplicated and re-ordered entries (:func:`describe_misbinding`).

Files without these attributes (another tool's recording) are not compared: there is nothing to
compare with. Only the attributes present are compared.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

INDEX = "msflash:index"
ROLE = "msflash:role"
LED_LEVELS = "msflash:led_levels"
EXPOSURE_US = "msflash:exposure_us"
GAIN = "msflash:gain"

_RELATIVE_TOLERANCE = 1e-6
"""Numbers stored as 32-bit attributes (EXR) round-trip to about 1e-7; JSON ones exactly."""


@dataclass(frozen=True)
class SelfDescription:
    """What a frame file says about the entry it was written for (None: not said)."""

    index: int | None
    role: str | None
    led_levels: tuple[float, ...] | None
    exposure_us: float | None
    gain: float | None

    @classmethod
    def from_attributes(cls, attributes: Mapping[str, Any]) -> SelfDescription:
        """Read the ``msflash:*`` attributes; a value of the wrong type counts as not said."""

        def number(key: str) -> float | None:
            value = attributes.get(key)
            return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None

        index = attributes.get(INDEX)
        role = attributes.get(ROLE)
        levels = attributes.get(LED_LEVELS)
        levels_ok = isinstance(levels, list | tuple) and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in levels
        )
        return cls(
            index=int(index) if isinstance(index, int) and not isinstance(index, bool) else None,
            role=role if isinstance(role, str) else None,
            led_levels=tuple(float(v) for v in levels) if levels_ok else None,  # type: ignore[union-attr]
            exposure_us=number(EXPOSURE_US),
            gain=number(GAIN),
        )

    def summary(self) -> str:
        """``role, LED levels […], exposure µs, gain`` for what is said."""
        parts = []
        if self.role is not None:
            parts.append(f"role {self.role}")
        if self.led_levels is not None:
            parts.append("LED levels [" + ", ".join(f"{v:g}" for v in self.led_levels) + "]")
        if self.exposure_us is not None:
            parts.append(f"exposure {self.exposure_us:g} µs")
        if self.gain is not None:
            parts.append(f"gain {self.gain:g}")
        return ", ".join(parts)


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=_RELATIVE_TOLERANCE, abs_tol=1e-12)


def disagreements(
    said: SelfDescription, index: int, role: str, led_levels: Sequence[float], exposure_us: float, gain: float
) -> list[str]:
    """The fields where the file's own description differs from the entry (empty: they agree)."""
    found = []
    if said.index is not None and said.index != index:
        found.append(f"index {said.index}")
    if said.role is not None and said.role != role:
        found.append(f"role {said.role}")
    if said.led_levels is not None and (
        len(said.led_levels) != len(led_levels) or not all(_close(a, b) for a, b in zip(said.led_levels, led_levels))
    ):
        found.append("LED levels")
    if said.exposure_us is not None and not _close(said.exposure_us, exposure_us):
        found.append("exposure")
    if said.gain is not None and not _close(said.gain, gain):
        found.append("gain")
    return found


def binding_problem(
    where: str,
    said: SelfDescription,
    index: int,
    role: str,
    led_levels: Sequence[float],
    exposure_us: float,
    gain: float,
) -> str | None:
    """One line naming the entry (``where``) and what its file says of itself (``said``), when they disagree;
    None when they agree."""
    fields = disagreements(said, index, role, led_levels, exposure_us, gain)
    if not fields:
        return None
    levels = "[" + ", ".join(f"{v:g}" for v in led_levels) + "]"
    written_for = f"frames[{said.index}]" if said.index is not None else "another entry"
    return (
        f"{where} was written for {written_for} ({said.summary()}), not for this entry (role {role}, LED levels "
        f"{levels}, exposure {exposure_us:g} µs, gain {gain:g}); expected each entry to name its own frame "
        "(entries swapped, duplicated or re-ordered in sequence.json?)"
    )


def describe_misbinding(index: int, said_index: int | None, said_indices: Sequence[int | None]) -> str:
    """How entry ``index`` is misbound, from the indices every entry's file says: swapped, duplicated or re-ordered.

    ``said_index``: the index its file says (None: it does not say, or says its own but other fields differ).
    """
    if said_index is None or said_index == index:
        return "its file's role, LED levels, exposure or gain differ from the entry (the entry was edited?)"
    others = [j for j, said in enumerate(said_indices) if said == said_index and j != index]
    if others:
        return f"duplicated: frames[{others[0]}] names a file written for frames[{said_index}] too"
    if 0 <= said_index < len(said_indices) and said_indices[said_index] == index:
        return f"swapped with frames[{said_index}]"
    return f"re-ordered: its file was written for frames[{said_index}]"
