"""Run the camera-loss child (``tests/acquisition/devices/camera_loss_child.py``) as its test does, many times.

Run as ``python -m tests.harness.camera_loss_repeat N SCENARIO...`` from the repository root with
it on ``PYTHONPATH``: per repetition and scenario (``camera``, ``capture``, ``silent``), the
process fake on 127.0.0.1, the child, the fake killed, an answering fake started. Prints each
repetition that did not end well (``signal N``, ``hang``, ``noready``) and a tally; the child's
stderr (and, for a hang, ``gdb``'s backtrace of every thread) go to ``camera-loss-*.txt`` in a
temporary folder it names. ``docs/steady-tests.md`` §2 runs it under load.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.acquisition.support.gvcp_port import gvcp_port_in_use

REPO = Path(__file__).resolve().parents[2]
CHILD = REPO / "tests" / "acquisition" / "devices" / "camera_loss_child.py"


def fake(serial: str, xml: str) -> subprocess.Popen:
    p = subprocess.Popen(
        ["arv-fake-gv-camera-0.8", "-i", "127.0.0.1", "-s", serial, "-g", xml],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    while not gvcp_port_in_use():
        time.sleep(0.01)
    return p


BOOT = (
    "import faulthandler,sys,runpy; faulthandler.dump_traceback_later(float(sys.argv.pop(1)), exit=False); "
    "sys.argv=sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')"
)


def once(scenario: str, work: Path, probe_dead: bool, xml: str, gv_fake) -> tuple[str, str]:  # noqa: ANN001
    work.mkdir(parents=True)
    with gv_fake.gvcp_port_lock():
        f = fake("S", xml)
        child = subprocess.Popen(
            [sys.executable, "-X", "faulthandler", "-c", BOOT, "40", str(CHILD), scenario, str(work)],
            cwd=REPO,
            text=True,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        line = child.stdout.readline().strip()
        if line != "READY":
            child.kill()
            f.kill()
            f.wait()
            return "noready", child.stderr.read()[-2000:]
        f.send_signal(signal.SIGKILL)
        f.wait()
        if probe_dead:
            child.stdin.write("KILLED\n")
            child.stdin.flush()
            child.stdout.readline()
        a = fake("SR", xml)
        child.stdin.write("ANSWERING\n" if probe_dead else "KILLED\n")
        child.stdin.flush()
        try:
            out, err = child.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            bt = subprocess.run(
                ["gdb", "-p", str(child.pid), "-batch", "-ex", "thread apply all bt"], capture_output=True, text=True
            ).stdout
            child.kill()
            out, err = child.communicate()
            a.kill()
            a.wait()
            return "hang", err[-6000:] + "\n---GDB---\n" + bt[-20000:]
        a.kill()
        a.wait()
    if child.returncode < 0:
        return f"signal {-child.returncode}", err[-6000:]
    return ("ok" if child.returncode == 0 else f"rc {child.returncode}"), err[-1500:]


def main() -> None:
    """Repeat the scenarios named on the command line."""
    from msflash.acquisition.devices.aravis import gv_fake
    from msflash.acquisition.devices.aravis.discovery import FAKE_SFNC_XML

    xml = str(FAKE_SFNC_XML)
    n = int(sys.argv[1])
    scen = sys.argv[2:]
    tmp = Path(tempfile.mkdtemp(prefix="camera-loss-"))
    tally: dict = {}
    for i in range(n):
        for s in scen:
            what, detail = once(s, tmp / f"{s}{i}", s == "silent", xml, gv_fake)
            tally[(s, what)] = tally.get((s, what), 0) + 1
            if what != "ok":
                (tmp / f"camera-loss-{s}-{i}.txt").write_text(detail)
                print(s, i, what, flush=True)
    print(tally)
    print(f"details in {tmp}")


if __name__ == "__main__":
    main()
