"""The Aravis GigE Vision fake camera served on 127.0.0.1 (one per machine: the GVCP port lock)."""

from __future__ import annotations

import fcntl
import logging
import os
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from msflash.acquisition.devices.aravis.discovery import (
    FAKE_SFNC_XML,
    _builtin_fake_xml_path,
)
from msflash.acquisition.devices.aravis.gi_typelib import Aravis
from msflash.acquisition.errors import CameraError

log = logging.getLogger(__name__)

GVCP_LOCK_PATH = Path(tempfile.gettempdir()) / "msflash-gvcp-127.0.0.1-3956.lock"
"""One GigE Vision fake can listen on 127.0.0.1:3956 at a time on this machine."""
GVCP_PORT = 3956
"""The GigE Vision control port (UDP)."""
_GV_MODEL_NAME_REGISTER = 0x68
"""GigE Vision bootstrap register of the model name (32 bytes), which the fake fills with "Fake"."""


def gvcp_port_holder(address: str = "127.0.0.1", port: int = GVCP_PORT) -> str | None:
    """Why ``address:port`` cannot be bound by itself (another program holds it), or None when it is free.

    The probe binds without ``SO_REUSEADDR``: the Aravis GigE Vision fake binds its control port *with* address
    reuse, so a second fake on the same address starts without error and a camera opened there may be the other
    program's (docs/aravis-facts.md). Only an exclusive bind tells.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((address, port))
        except OSError as err:
            return err.strerror or str(err)
    return None


_gvcp_hold: dict[str, Any] = {"count": 0, "fd": None}
"""This process's hold of :func:`gvcp_port_lock`: how many holders, and the locked file's descriptor."""
_gvcp_hold_lock = threading.Lock()


@contextmanager
def gvcp_port_lock(timeout_s: float = 120.0) -> Iterator[None]:
    """Hold the machine-wide lock on the GigE Vision control port 3956 of 127.0.0.1.

    Fakes in parallel test workers, benches and rigs take turns; the kernel releases the ``flock`` if the holder
    dies. A process that holds it already holds it again at once (a second fake it starts then finds the port
    bound and is refused, :meth:`AravisGvFake.start`).

    Raises
    ------
    CameraError
        The lock was not obtained within ``timeout_s``.
    """
    with _gvcp_hold_lock:
        if _gvcp_hold["count"]:
            _gvcp_hold["count"] += 1
            fd = None
        else:
            fd = os.open(GVCP_LOCK_PATH, os.O_CREAT | os.O_RDWR, 0o666)
    if fd is not None:
        try:
            deadline = time.monotonic() + timeout_s
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() > deadline:
                        raise CameraError(
                            f"GigE Vision fake: port 127.0.0.1:3956 busy for {timeout_s:g} s "
                            f"(lock {GVCP_LOCK_PATH}); expected it free — another fake is running"
                        ) from None
                    time.sleep(0.02)
        except BaseException:
            os.close(fd)
            raise
        with _gvcp_hold_lock:
            _gvcp_hold["count"] += 1
            _gvcp_hold["fd"] = fd
    try:
        yield
    finally:
        with _gvcp_hold_lock:
            _gvcp_hold["count"] -= 1
            if not _gvcp_hold["count"]:
                held, _gvcp_hold["fd"] = _gvcp_hold["fd"], None
                fcntl.flock(held, fcntl.LOCK_UN)
                os.close(held)


class AravisGvFake:
    """The Aravis GigE Vision fake camera served on 127.0.0.1 by this process.

    It speaks real GVCP/GVSP, honours software triggers and exposes its registers, so
    :class:`AravisCamera` opened on ``address`` with ``interfaces=("gige",)`` exercises the whole
    GigE Vision path without a network. Use as a context manager; it holds :func:`gvcp_port_lock`.

    Parameters
    ----------
    genicam_xml
        GenICam description (defaults to msflash's SFNC XML); ``None`` for the fake's built-in one.
    trigger_frequency_hz
        How often the fake checks for a software trigger (its trigger-to-frame latency).
    model
        Model name the fake reports (its bootstrap register; the XML's ``DeviceModelName`` reads it),
        None for Aravis's "Fake". Camera profiles are matched on it.
    registers
        Registers written when the fake starts (address → 32-bit value): a camera's power-on state
        (``GainAuto`` on, a gain register's first value).

    Examples
    --------
    A rig on the fake (no network beyond loopback, no discovery)::

        with AravisGvFake(serial="RIG01") as fake, \
                AravisCamera(fake.address, interfaces="gige", pixel_format="Mono16") as camera:
            camera.prepare(plan)
            camera.start()
            ...
    """

    address = "127.0.0.1"

    def __init__(
        self,
        serial: str = "MSF0001",
        genicam_xml: str | os.PathLike[str] | None = FAKE_SFNC_XML,
        trigger_frequency_hz: float = 1000.0,
        lost_packet_ratio: float = 0.0,
        lock_timeout_s: float = 120.0,
        model: str | None = None,
        registers: dict[int, int] | None = None,
    ) -> None:
        self.serial = serial
        self.model = model
        self._registers = dict(registers or {})
        # None: the fake's built-in description, named explicitly — given no file, Aravis's fake
        # reads the process-wide one last set for the in-process fake (the tests set it).
        self._xml = str(genicam_xml) if genicam_xml is not None else _builtin_fake_xml_path()
        self._frequency = trigger_frequency_hz
        self._lost = lost_packet_ratio
        self._lock_timeout_s = lock_timeout_s
        self._lock: Any = None
        self._fake: Any = None

    def __enter__(self) -> AravisGvFake:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        """Take the port lock and start serving.

        Raises
        ------
        CameraError
            The port is held by another program (not an msflash fake: those take the lock), whose
            camera would answer in place of this one (:func:`gvcp_port_holder`).
        """
        self._lock = gvcp_port_lock(self._lock_timeout_s)
        self._lock.__enter__()
        try:
            held = gvcp_port_holder(self.address)
            if held is not None:
                raise CameraError(
                    f"GigE Vision fake {self.serial}: {self.address}:{GVCP_PORT} is already bound by another "
                    f"program ({held}) — another GigE Vision fake such as arv-fake-gv-camera-0.8?; expected it "
                    "free: both would share the port and msflash could open the other camera — stop it, or use "
                    "it with --rig hw --camera 127.0.0.1 --interfaces gige"
                )
            fake = Aravis.GvFakeCamera.new_full(self.address, self.serial, self._xml)
            if not fake.is_running():
                raise CameraError(
                    f"GigE Vision fake {self.serial}: cannot listen on {self.address}:3956; "
                    "expected the port free — is an arv-fake-gv-camera running?"
                )
            fake.set_property("gvsp-lost-ratio", float(self._lost))
            fake.get_fake_camera().set_trigger_frequency(self._frequency)
            self._fake = fake
            if self.model is not None:
                self._write_model_name(self.model)
            for address, value in self._registers.items():
                self.write_register(address, value)
        except BaseException:
            self._lock.__exit__(None, None, None)
            self._lock = None
            raise

    def close(self) -> None:
        """Stop serving and release the port; idempotent."""
        self._fake = None  # finalising the GObject stops its thread and closes its sockets
        if self._lock is not None:
            self._lock.__exit__(None, None, None)
            self._lock = None

    def _write_model_name(self, model: str) -> None:
        data = model.encode("ascii")[:31].ljust(32, b"\0")
        for offset in range(0, 32, 4):
            self.write_register(_GV_MODEL_NAME_REGISTER + offset, int.from_bytes(data[offset : offset + 4], "big"))

    def read_register(self, address: int) -> int:
        """A 32-bit register of the fake, as the camera side sees it."""
        ok, value = self._fake.get_fake_camera().read_register(address)
        if not ok:
            raise CameraError(
                f"GigE Vision fake {self.serial}: register 0x{address:x} unreadable; expected an address below 0x10000"
            )
        return int(value)

    def write_register(self, address: int, value: int) -> None:
        """Write a 32-bit register of the fake (simulates the camera changing state)."""
        self._fake.get_fake_camera().write_register(address, value)
