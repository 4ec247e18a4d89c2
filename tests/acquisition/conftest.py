"""Fixtures for the acquisition tests.

Aravis fixtures
---------------
``aravis``
    The :mod:`acquisition.devices.aravis.camera` module; skips the test (with the reason) when the Aravis
    typelib is missing.
``fake_camera``
    :class:`AravisCamera` on the in-process ``Fake_1`` (Fake interface only, so nothing is
    broadcast), Mono16 at 320x240. It ignores triggers and has no Line/Chunk features.
``sfnc_fake_camera``
    The same with msflash's SFNC GenICam XML loaded.
``gv_fake`` / ``gv_camera``
    The GigE Vision fake served on 127.0.0.1 inside the test process, and an ``AravisCamera``
    opened on it by address (no discovery).
``hw_calibration``, ``hw_booth_port``, ``led_spectra_csv``
    The hardware rig's calibration, booth and LED spectra (:mod:`tests.acquisition.support.hw_rig`).
``gv_fake_process``
    A factory starting ``arv-fake-gv-camera-0.8 -i 127.0.0.1`` as a separate process (to kill it,
    to drop packets with ``-r``, to serve Aravis's own XML, or to be another program's camera on
    the port).

Parallel workers: the GigE Vision fake binds 127.0.0.1:3956 and the machine has no other
loopback address configured (the fake needs an interface that owns its address), so two fakes
cannot run at once. Every fixture starting one holds ``gv_fake.gvcp_port_lock`` (an
``flock`` that the kernel releases if a worker dies) for the duration of one test only, so
xdist workers, and other suites on the machine using the same lock, take turns test by test.
"""

from __future__ import annotations

import ctypes
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from tests.acquisition.support.gvcp_port import gvcp_port_in_use
from tests.acquisition.support.hw_rig import hw_booth_port, hw_calibration, led_spectra_csv  # noqa: F401 - fixtures

FAKE_GV_TOOL = "arv-fake-gv-camera-0.8"


@pytest.fixture
def aravis() -> ModuleType:
    """The Aravis camera module, or a skip naming what is missing."""
    try:
        import msflash.acquisition.devices.aravis.camera as module
    except ImportError as err:
        pytest.skip(f"Aravis unavailable: {err}")
    return module


@pytest.fixture
def fake_camera(aravis: ModuleType) -> Iterator[Any]:
    """AravisCamera on the in-process Fake_1, Mono16 320x240, built-in GenICam XML."""
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    camera = aravis.AravisCamera("Fake_1", interfaces="fake", pixel_format="Mono16", roi=(0, 0, 320, 240))
    try:
        yield camera
    finally:
        camera.close()


@pytest.fixture
def sfnc_fake_camera(aravis: ModuleType) -> Iterator[Any]:
    """AravisCamera on the in-process Fake_1 loaded with msflash's SFNC XML."""
    from msflash.acquisition.devices.aravis.discovery import FAKE_SFNC_XML
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(FAKE_SFNC_XML)
    try:
        camera = aravis.AravisCamera("Fake_1", interfaces="fake", pixel_format="Mono8", roi=(0, 0, 128, 96))
    finally:
        use_fake_genicam(None)  # the XML is read when the fake device is created
    try:
        yield camera
    finally:
        camera.close()


@pytest.fixture
def gv_fake(aravis: ModuleType) -> Iterator[Any]:
    """The GigE Vision fake on 127.0.0.1 in this process, with the SFNC XML and 1 kHz trigger polling."""
    from msflash.acquisition.devices.aravis.gv_fake import AravisGvFake

    with AravisGvFake(serial="MSFTEST1") as fake:
        yield fake


@pytest.fixture
def gv_camera(aravis: ModuleType, gv_fake: Any) -> Iterator[Any]:
    """AravisCamera opened on the in-process GigE Vision fake by IP address, Mono8 128x96."""
    camera = aravis.AravisCamera(gv_fake.address, interfaces="gige", pixel_format="Mono8", roi=(0, 0, 128, 96))
    try:
        yield camera
    finally:
        camera.close()


def _die_with_parent() -> None:
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG


@pytest.fixture
def gv_fake_process(aravis: ModuleType) -> Iterator[Callable[..., subprocess.Popen[bytes]]]:
    """Factory: start ``arv-fake-gv-camera-0.8 -i 127.0.0.1`` (holding the port lock) and return the process."""
    from msflash.acquisition.devices.aravis.discovery import FAKE_SFNC_XML
    from msflash.acquisition.devices.aravis.gv_fake import gvcp_port_lock

    if shutil.which(FAKE_GV_TOOL) is None:
        pytest.skip(f"{FAKE_GV_TOOL} not installed (Debian package aravis-tools)")
    stack = ExitStack()
    processes: list[subprocess.Popen[bytes]] = []

    def start(
        serial: str = "MSFPROC1", lost_per_thousand: float | None = None, builtin_xml: bool = False
    ) -> subprocess.Popen[bytes]:
        if not processes:  # one lock for the whole test (this process's later holds nest in it)
            stack.enter_context(gvcp_port_lock())
        command = [FAKE_GV_TOOL, "-i", "127.0.0.1", "-s", serial]
        if not builtin_xml:  # builtin_xml: Aravis's own description (GainRaw 0-10, no Gain)
            command += ["-g", str(FAKE_SFNC_XML)]
        if lost_per_thousand is not None:
            command += ["-r", str(lost_per_thousand)]
        # PR_SET_PDEATHSIG: the fake dies with this worker even if the worker crashes, so no
        # orphan keeps 127.0.0.1:3956 after the lock is gone.
        process = subprocess.Popen(
            command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=_die_with_parent
        )
        processes.append(process)
        deadline = time.monotonic() + 10.0
        while not gvcp_port_in_use():  # wait until the fake has bound its control port
            if process.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"{FAKE_GV_TOOL} did not start listening on 127.0.0.1:3956 (exit status {process.poll()})")
            time.sleep(0.01)
        return process

    try:
        yield start
    finally:
        for process in processes:
            if process.poll() is None:
                process.send_signal(signal.SIGKILL)
            process.wait(timeout=10)
        stack.close()


@pytest.fixture(scope="module")
def base_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A test sequence (tests.helpers.write_test_sequence), written once a module."""
    from tests.helpers import write_test_sequence

    return write_test_sequence(tmp_path_factory.mktemp("sequence") / "seq")


@pytest.fixture
def sequence(base_sequence: Path, tmp_path: Path) -> Path:
    """A fresh copy of :func:`base_sequence` for each test (which may damage it)."""
    copy = tmp_path / "seq"
    shutil.copytree(base_sequence, copy)
    return copy
