"""Random link faults for the booth emulator, as ``msflash booth-emulator --fault`` gives them.

A fault specification is a comma-separated list of ``KIND:P`` items, each kind at most once:

- ``drop:P``: each outgoing frame (reply or event) loses one byte with probability ``P``;
- ``flip:P``: each outgoing frame has one bit flipped with probability ``P``;
- ``garble:P``: each request line from the host has one bit flipped before the booth reads it;
- ``stall:P[:SECONDS]``: at each request line, with probability ``P``, the booth stops reading
  and answering (that request is lost) for ``SECONDS``, or for good when omitted; its firmware
  keeps running, so its watchdog still switches the LEDs off;
- ``close:P``: at each request line, with probability ``P``, the booth hangs up the link (as an
  unplugged cable; the emulator switches its LEDs off).

Draws come from one seeded generator in a fixed order (per request: garble, stall, close; per
outgoing frame: drop, flip), so a seed replays the same faults for the same traffic. The first
``after`` request lines are never faulted (the host can open and identify the booth).
"""

from __future__ import annotations

import json
import math
import os
import random
import threading
from dataclasses import dataclass
from pathlib import Path

from msflash.led_controller.emulator import BoothEmulator

FAULT_SPEC_KINDS = ("drop", "flip", "garble", "stall", "close")
"""Fault kinds ``--fault`` accepts."""

_REQUEST_KINDS = ("garble", "stall", "close")
_SEND_KINDS = ("drop", "flip")
_FORM = "KIND:P (P a probability in [0, 1]; stall:P[:SECONDS]) with KIND one of " + ", ".join(FAULT_SPEC_KINDS)


@dataclass(frozen=True)
class FaultRate:
    """One ``--fault`` item: a kind, its probability per frame and (stall) its duration."""

    kind: str
    """One of :data:`FAULT_SPEC_KINDS`."""
    probability: float
    """Probability per frame (outgoing frames for drop and flip, request lines for the others)."""
    seconds: float | None = None
    """How long a stall lasts in seconds; None: for good (stall only)."""


def _number(item: str, field: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f"--fault item {item!r}: {field} {text!r} is not a finite number; expected {_FORM}")
    return value


def parse_fault_spec(text: str) -> tuple[FaultRate, ...]:
    """Parse a ``--fault`` specification (see the module notes).

    Raises
    ------
    ValueError
        One line naming the first bad item and what was expected.

    Examples
    --------
    >>> parse_fault_spec("drop:0.01,stall:0.5:2")
    (FaultRate(kind='drop', probability=0.01, seconds=None), FaultRate(kind='stall', probability=0.5, seconds=2.0))
    >>> parse_fault_spec("drop:2")
    Traceback (most recent call last):
    ValueError: --fault item 'drop:2': probability 2 outside [0, 1]; expected KIND:P (P a probability in [0, 1]; ...
    """
    rates: list[FaultRate] = []
    for item in text.split(","):
        fields = item.strip().split(":")
        kind = fields[0]
        if kind not in FAULT_SPEC_KINDS:
            raise ValueError(f"--fault item {item!r}: kind {kind!r} unknown; expected {_FORM}")
        if any(rate.kind == kind for rate in rates):
            raise ValueError(f"--fault item {item!r}: {kind} given twice; expected each kind at most once")
        most = 3 if kind == "stall" else 2
        if not 2 <= len(fields) <= most:
            raise ValueError(f"--fault item {item!r}: {len(fields) - 1} value(s); expected {_FORM}")
        probability = _number(item, "probability", fields[1])
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"--fault item {item!r}: probability {fields[1]} outside [0, 1]; expected {_FORM}")
        seconds = None
        if len(fields) == 3:
            seconds = _number(item, "stall seconds", fields[2])
            if seconds <= 0:
                raise ValueError(
                    f"--fault item {item!r}: stall seconds {fields[2]} not positive; expected "
                    "stall:P[:SECONDS] with SECONDS > 0 (omitted: the booth never recovers)"
                )
        rates.append(FaultRate(kind, probability, seconds))
    return tuple(rates)


class FaultInjector:
    """Draws the faults of ``rates`` for ``emulator`` as its frames pass (its :attr:`BoothEmulator.fault_hook`).

    Parameters
    ----------
    emulator
        The emulator to fault; its ``fault_hook`` is taken.
    rates
        What :func:`parse_fault_spec` returned.
    seed
        Seed of the generator (the same seed and traffic give the same faults).
    after
        Request lines passed through before any fault is drawn.
    """

    def __init__(self, emulator: BoothEmulator, rates: tuple[FaultRate, ...], *, seed: int = 0, after: int = 0) -> None:
        if after < 0:
            raise ValueError(f"FaultInjector: after {after}; expected a count ≥ 0")
        self._emulator = emulator
        self._rates = {rate.kind: rate for rate in rates}
        self._random = random.Random(seed)
        self._after = after
        self.requests = 0
        """Request lines seen."""
        self.injected = {kind: 0 for kind in FAULT_SPEC_KINDS}
        """Faults injected so far, by kind."""
        emulator.fault_hook = self._on_frame

    def _draw(self, kind: str) -> bool:
        rate = self._rates.get(kind)
        return rate is not None and self._random.random() < rate.probability

    def _on_frame(self, moment: str) -> None:
        if moment == "request":
            self.requests += 1
        if self.requests <= self._after:
            return
        for kind in _REQUEST_KINDS if moment == "request" else _SEND_KINDS:
            if not self._draw(kind):
                continue
            self.injected[kind] += 1
            self._emulator.inject_fault("garble_input" if kind == "garble" else kind)
            seconds = self._rates[kind].seconds
            if kind == "stall" and seconds is not None:
                timer = threading.Timer(seconds, self._emulator.resume)
                timer.daemon = True
                timer.start()
            if kind in ("stall", "close"):
                return  # the request is lost with the booth: nothing more to draw for it


def emulator_state(emulator: BoothEmulator, injector: FaultInjector | None, *, port: str, link: str) -> dict:
    """What ``--state-file`` records: the booth's state, LEDs, watchdog, the faults injected so far and
    ``boots``, how often its firmware started (power-up, then once per reset by a host's open)."""
    snapshot = emulator.snapshot()
    return {
        "port": port,
        "link": link,
        **snapshot,
        "boots": emulator.boots,
        "requests": injector.requests if injector is not None else None,
        "faults": dict(injector.injected) if injector is not None else {},
    }


def write_state_file(path: Path, state: dict) -> None:
    """Replace ``path`` with ``state`` as JSON (temporary file and rename: a reader never sees half of it)."""
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(json.dumps(state, indent=1) + "\n")
    os.replace(temporary, path)
