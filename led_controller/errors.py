"""Errors of the booth package (driver, discovery).

Each class also inherits the matching built-in exception, so callers that only know the
standard library still catch them. Messages follow ``"<where>: <what is wrong>; expected
<what>"`` and add a remedy when one is known.
"""

from __future__ import annotations


class BoothError(OSError):
    """The LED booth failed, refused a command or its link was lost."""

    def __init__(self, message: str) -> None:
        # OSError's own constructor treats two or more arguments as (errno, strerror);
        # keeping one positional argument keeps ``str(err)`` equal to the message.
        super().__init__(message)


class BoothNotFoundError(BoothError, LookupError):
    """No booth at the given port, or none among the serial ports; the message lists what was found."""


class BoothTimeoutError(BoothError, TimeoutError):
    """The booth did not answer ``command`` within ``timeout_s``; the message names the port too."""

    def __init__(self, message: str, *, command: str, timeout_s: float) -> None:
        super().__init__(message)
        self.command = command
        self.timeout_s = timeout_s


class BoothProtocolError(BoothError):
    """A frame broke the booth protocol (bad checksum or length, unexpected form).

    ``command`` is the command whose reply was bad (None: an unsolicited line), ``expected`` the
    frame's expected form in words, ``raw`` the line without its terminator.
    """

    def __init__(self, message: str, *, command: str | None, expected: str, raw: bytes) -> None:
        super().__init__(message)
        self.command = command
        self.expected = expected
        self.raw = raw
