"""The user-file fuzzer's worker (issue 32 item 5): every file msflash reads besides a sequence folder.

``python -m tests.acquisition.fuzz.user_file_fuzz_worker --examples N [--memory-gib G] [--example-s S]``

One process, capped as :mod:`tests.acquisition.fuzz.sequence_fuzz_worker` is (``RLIMIT_AS`` its size after
imports plus ``--memory-gib``; ``SIGALRM`` after ``--example-s`` seconds per example), builds one valid
set of inputs per *surface* (a command and the files it reads), records the command's result on them,
then lets Hypothesis mutate one file of one surface at a time
(:mod:`tests.acquisition.fuzz.user_file_mutations`, which also holds the rule) and runs the command through
``main([...])``. Surfaces:

- ``target``: ``flash SEQ --mode complementary --target FILE.csv``;
- ``calibration``: ``estimate SEQ --calibration DIR`` (``calibration.json``, ``camera.csv``, ``leds.csv``
  as ``calibrate camera --simulate`` and ``calibrate leds`` wrote them);
- ``leds-<program>``: ``calibrate leds`` on three LED exports, a dark and ``--spectrometer-response``,
  as each spectrometer program writes them (:mod:`tests.calibration.spectrometer_writers`);
- ``chart``: ``calibrate camera --simulate --chart FILE.csv``;
- ``ambient``, ``scene``, ``led-spectra``, ``sim-camera``: ``capture --rig sim`` with that option's CSV;
- ``reference-chart``: ``estimate SEQ --model prior --reference-chart FILE.json``;
- ``profiles``: the camera profiles (``genicam/profiles.json``; no option names another file, so
  :func:`load_profiles` on a path, every profile's patterns matched, and its one-line error as the CLI
  prints it).

Exit 0 and a JSON summary on the last stdout line if no example broke the rule; 1 with Hypothesis'
falsifying example otherwise.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import hashlib
import io
import json
import math
import re
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hypothesis
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from msflash.acquisition.app.cli import main
from msflash.acquisition.devices.aravis.discovery import PROFILES_JSON
from msflash.acquisition.devices.aravis.profiles import load_profiles
from msflash.acquisition.errors import CameraSettingError
from msflash.acquisition.sequence.reader import read_sequence
from msflash.calibration.files import load_calibration
from msflash.processing import datasets
from msflash.processing.spectra import DEFAULT_GRID
from tests.acquisition.fuzz.user_file_mutations import (
    Expect,
    FileMutation,
    apply_file_mutation,
    every_special,
    file_mutations,
)
from tests.acquisition.support.fuzz_runner import ExampleTimeout, example_alarm, fuzz_settings, worker_main
from tests.calibration.spectrometer_writers import FORMATS, Instrument, export_text
from tests.helpers import write_test_sequence

Result = tuple[int, str, str, Any, str | None]
"""Exit status, stdout, stderr, a fingerprint of the numbers (None: nothing to compare), a sanity problem."""


@dataclass(frozen=True)
class UserFile:
    """One file a surface reads: its path under the surface's folder, its format, one spectrum or more."""

    name: str
    kind: str
    """``csv``, ``export`` (a spectrometer program's text) or ``json``."""
    single: bool = False


@dataclass(frozen=True)
class Surface:
    """A command and the files it reads."""

    name: str
    files: tuple[UserFile, ...]
    argv: Callable[[Path, Path], list[str]] | None
    """(the surface's folder, an output folder) → the command line; None: :func:`run_profiles`."""
    outcome: Callable[[str, Path], tuple[Any, str | None]]
    """(stdout, output folder) → (fingerprint of the numbers, a problem with them or None), on exit 0."""


# -- sanity of what a command gave on exit 0 ------------------------------------------------------------
def _numbers(value: Any) -> list[float]:
    if isinstance(value, dict):
        return [n for v in value.values() for n in _numbers(v)]
    if isinstance(value, list):
        return [n for v in value for n in _numbers(v)]
    if isinstance(value, bool) or not isinstance(value, int | float):
        return []
    return [float(value)]


TIMINGS = re.compile(r"(^|_)(s|ms|seconds|elapsed|time)$")


def _json_numbers(payload: Any) -> list[float]:
    """The numbers of a JSON answer, leaving out timings (they differ between runs)."""
    if isinstance(payload, dict):
        return [n for k, v in payload.items() if not TIMINGS.search(str(k)) for n in _json_numbers(v)]
    if isinstance(payload, list):
        return [n for v in payload for n in _json_numbers(v)]
    return _numbers(payload)


def json_outcome(stdout: str, out: Path) -> tuple[Any, str | None]:
    """A JSON answer on stdout: every number finite (NaN and infinities would be written as such)."""
    numbers = _json_numbers(json.loads(stdout))
    bad = [n for n in numbers if not math.isfinite(n)]
    return tuple(numbers), (f"{len(bad)} non-finite numbers in the JSON answer" if bad else None)


def calibration_outcome(stdout: str, out: Path) -> tuple[Any, str | None]:
    """A calibration written to ``out``: read back, its spectra finite."""
    calibration = load_calibration(out)
    arrays = [
        spectra.values
        for spectra in (calibration.led_spectra, calibration.camera_responsivities, calibration.chart_reflectances)
        if spectra is not None
    ]
    digest = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays)).hexdigest()
    bad = [a for a in arrays if not np.all(np.isfinite(a))]
    return digest, ("non-finite values in the calibration written" if bad else None)


def sequence_outcome(stdout: str, out: Path) -> tuple[Any, str | None]:
    """A sequence captured to ``out``: read back, every frame loaded, its LED spectra finite."""
    sequence = read_sequence(out / "sequence")
    digest = hashlib.sha256()
    for index in range(len(sequence.frames)):
        digest.update(np.ascontiguousarray(sequence.load_frame(index)).tobytes())
    spectra = np.stack([np.asarray(led.spd, float) for led in sequence.leds])
    digest.update(spectra.tobytes())
    return digest.hexdigest(), (None if np.all(np.isfinite(spectra)) else "non-finite LED spectra recorded")


# -- the valid inputs -------------------------------------------------------------------------------------
def _csv(path: Path, wavelengths: np.ndarray, columns: dict[str, np.ndarray]) -> None:
    lines = ["wavelength_nm," + ",".join(columns)]
    lines += [
        ",".join([f"{w:g}"] + [f"{column[i]:.6g}" for column in columns.values()]) for i, w in enumerate(wavelengths)
    ]
    path.write_text("\n".join(lines) + "\n")


def _spectra_csv(path: Path, spectra: Any, names: list[str] | None = None) -> None:
    _csv(path, spectra.wavelengths_nm, {n: spectra.values[:, i] for i, n in enumerate(names or spectra.names)})


def build_surfaces(work: Path, sequence: Path) -> list[Surface]:
    """Every surface with its valid files written under ``work/<surface>/``."""
    surfaces: list[Surface] = []

    def folder(name: str) -> Path:
        path = work / name
        path.mkdir(parents=True)
        return path

    # flash --target
    f = folder("target")
    d65 = datasets.illuminant("D65", DEFAULT_GRID)
    _spectra_csv(f / "target.csv", d65, ["D65"])
    surfaces.append(
        Surface(
            "target",
            (UserFile("target.csv", "csv", single=True),),
            lambda f, o: [
                "flash",
                str(sequence),
                "--mode",
                "complementary",
                "--target",
                str(f / "target.csv"),
                "--json",
            ],
            json_outcome,
        )
    )

    # estimate --calibration: what calibrate camera --simulate wrote, with the sequence's LEDs added
    f = folder("calibration")
    _quiet(["calibrate", "camera", "--simulate", "--out", str(f / "cal")])
    leds = datasets.paper_leds()
    document = json.loads((f / "cal" / "calibration.json").read_text())
    document["leds"] = {"file": "leds.csv", "names": list(leds.names), "unit": "energy"}
    (f / "cal" / "calibration.json").write_text(json.dumps(document, indent=1))
    _spectra_csv(f / "cal" / "leds.csv", leds)
    surfaces.append(
        Surface(
            "calibration",
            (
                UserFile("cal/calibration.json", "json"),
                UserFile("cal/camera.csv", "csv"),
                UserFile("cal/leds.csv", "csv"),
            ),
            lambda f, o: ["estimate", str(sequence), "--calibration", str(f / "cal"), "--json"],
            json_outcome,
        )
    )

    # calibrate leds, as each spectrometer program writes its exports
    instrument = Instrument.typical(3)
    truth = datasets.paper_leds().select([0, 3, 6])
    for form in FORMATS:
        f = folder(f"leds-{form}")
        rng = np.random.default_rng(1)
        names = []
        for index, time_s in enumerate((0.010, 0.005, 0.020)):
            column = truth.values[:, index] / truth.values[:, index].max()
            irradiance = np.interp(instrument.wavelengths_nm, truth.wavelengths_nm, column, left=0, right=0) * 250
            counts = instrument.counts(irradiance, time_s, 4, rng)
            (f / f"led{index}.txt").write_text(export_text(form, instrument.wavelengths_nm, counts, time_s, 4))
            names.append(f"led{index}.txt")
        dark = instrument.counts(None, 0.020, 16, rng)
        (f / "dark.txt").write_text(export_text(form, instrument.wavelengths_nm, dark, 0.020, 16, name="dark"))
        (f / "response.csv").write_text(
            "wavelength_nm,counts_per_s_per_irradiance\n"
            + "".join(f"{w:.4f},{r:.9g}\n" for w, r in zip(instrument.wavelengths_nm, instrument.response, strict=True))
        )
        surfaces.append(
            Surface(
                f"leds-{form}",
                tuple(UserFile(n, "export", single=True) for n in [*names, "dark.txt"])
                + (UserFile("response.csv", "csv", single=True),),
                lambda f, o, names=tuple(names): [
                    "calibrate",
                    "leds",
                    *(str(f / n) for n in names),
                    "--dark",
                    str(f / "dark.txt"),
                    "--spectrometer-response",
                    str(f / "response.csv"),
                    "--out",
                    str(o),
                    "--json",
                ],
                calibration_outcome,
            )
        )

    # calibrate camera --simulate --chart FILE.csv
    f = folder("chart")
    macbeth = datasets.macbeth()
    _spectra_csv(f / "chart.csv", macbeth)
    surfaces.append(
        Surface(
            "chart",
            (UserFile("chart.csv", "csv"),),
            lambda f, o: [
                "calibrate",
                "camera",
                "--simulate",
                "--chart",
                str(f / "chart.csv"),
                "--out",
                str(o),
                "--json",
            ],
            calibration_outcome,
        )
    )

    # capture --rig sim with each world option's CSV
    capture = ["capture", "--rig", "sim", "--seed", "0", "--exposure-us", "2000"]
    world = {
        "ambient": (datasets.illuminant("A", DEFAULT_GRID), ["tungsten"], ["--leds", "3"], True),
        "scene": (macbeth.select(list(range(6))), None, ["--leds", "3"], False),
        "led-spectra": (truth, None, [], False),
        "sim-camera": (datasets.camera_responsivities("NikonD100"), ["R", "G", "B"], ["--leds", "3"], False),
    }
    for option, (spectra, names, extra, single) in world.items():
        f = folder(option)
        _spectra_csv(f / f"{option}.csv", spectra, names)
        surfaces.append(
            Surface(
                option,
                (UserFile(f"{option}.csv", "csv", single=single),),
                lambda f, o, option=option, extra=tuple(extra): [
                    *capture,
                    *extra,
                    f"--{option}",
                    str(f / f"{option}.csv"),
                    "--out",
                    str(o),
                ],
                sequence_outcome,
            )
        )

    # estimate --reference-chart FILE.json
    f = folder("reference-chart")
    chart = {
        "patches": [
            {"rect": [4, 4, 16, 16], "wavelengths_nm": [400, 550, 700], "reflectance": [0.2, 0.5, 0.4]},
            {"rect": [30, 20, 16, 16], "wavelengths_nm": [400, 700], "reflectance": [0.8, 0.8]},
        ]
    }
    (f / "chart.json").write_text(json.dumps(chart, indent=1))
    surfaces.append(
        Surface(
            "reference-chart",
            (UserFile("chart.json", "json"),),
            lambda f, o: [
                "estimate",
                str(sequence),
                "--model",
                "prior",
                "--reference-chart",
                str(f / "chart.json"),
                "--json",
            ],
            json_outcome,
        )
    )

    # the camera profiles
    f = folder("profiles")
    shutil.copy(PROFILES_JSON, f / "profiles.json")
    surfaces.append(Surface("profiles", (UserFile("profiles.json", "json"),), None, lambda stdout, o: (stdout, None)))
    return surfaces


def _quiet(argv: list[str]) -> None:
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        status = main(argv)
    assert status == 0, stderr.getvalue()


def run_profiles(path: Path) -> tuple[int, str, str]:
    """:func:`load_profiles` on ``path``, each profile's patterns matched as :func:`match_profile` does;
    its error printed as the CLI prints a ``CameraSettingError`` (exit 2). Anything else escapes."""
    try:
        profiles = load_profiles(path)
        for vendor, model, _ in profiles:
            re.fullmatch(vendor, "The Imaging Source", re.IGNORECASE)
            re.fullmatch(model, "DFK 33UX264", re.IGNORECASE)
    except CameraSettingError as err:
        return 2, "", f"msflash: error: {err}\n"
    except Exception as err:  # what the CLI calls a bug
        return 1, "", f"msflash: unexpected {type(err).__name__}: {err}\n"
    return 0, repr(profiles), ""


def run_surface(surface: Surface, place: Path, out: Path) -> Result:
    """The command of ``surface`` on the files under ``place``: status, output, and what its numbers are."""
    shutil.rmtree(out, ignore_errors=True)
    if surface.argv is None:
        status, stdout_text, stderr_text = run_profiles(place / surface.files[0].name)
    else:
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            status = main(surface.argv(place, out))
        stdout_text, stderr_text = stdout.getvalue(), stderr.getvalue()
    fingerprint, problem = (None, None)
    if status == 0:
        try:
            fingerprint, problem = surface.outcome(stdout_text, out)
        except Exception as err:  # what the command wrote cannot be read back
            fingerprint, problem = None, f"exit 0, but its output cannot be read back: {err}"
    return status, stdout_text, stderr_text, fingerprint, problem


def judge(mutation: FileMutation, changed: UserFile, result: Result, baseline: Result) -> str | None:
    """What rule ``result`` breaks (None: none)."""
    status, stdout, stderr, fingerprint, problem = result
    if "Traceback" in stderr or "Traceback" in stdout:
        return "a traceback on the terminal"
    if status == 1:
        return "exit 1: " + (stderr.strip().splitlines() or ["(nothing on stderr)"])[-1]
    if status not in (0, 2):
        return f"exit status {status}"
    if status == 2:
        errors = [line for line in stderr.splitlines() if line.startswith("msflash: error:")]
        if len(errors) != 1:
            return f"exit 2 without exactly one 'msflash: error:' line: {stderr!r:.300}"
        names = {Path(changed.name).name, Path(changed.name).parent.name} - {""}
        if not any(name in errors[0] for name in names):
            return f"the error names neither {' nor '.join(sorted(names))}: {errors[0]!r:.300}"
    if status == 0 and mutation.expect is Expect.REFUSE:
        return "exit 0 on a file that must be refused"
    if status == 0 and problem:
        return problem
    if mutation.expect is Expect.SAME and (status, fingerprint) != (baseline[0], baseline[3]):
        return "the same data gave another result"
    if mutation.expect is Expect.SAME_OR_REFUSE and status == 0 and fingerprint != baseline[3]:
        return "the same data differently written gave other numbers"
    return None


def fuzz(examples: int, example_s: int, work: Path, collect: list[str] | None = None) -> collections.Counter:
    """Run ``examples`` derandomised examples (and each special file on each file of each surface).

    ``collect``: a list that receives every broken rule instead of stopping at the first (for a hunt).
    """
    sequence = write_test_sequence(work / "sequence")
    base = work / "base"
    surfaces = build_surfaces(base, sequence)
    out = work / "out"
    case = work / "case"
    outside = work / "outside"
    baselines = {s.name: run_surface(s, base / s.name, out) for s in surfaces}
    failed = {name: result[2][-400:] for name, result in baselines.items() if result[0] != 0 or result[4]}
    assert not failed, failed
    by_name = {s.name: s for s in surfaces}
    tally: collections.Counter = collections.Counter()

    @st.composite
    def cases(draw: st.DrawFn) -> tuple[str, int, FileMutation]:
        surface = by_name[draw(st.sampled_from(sorted(by_name)), label="surface")]
        index = draw(st.integers(0, len(surface.files) - 1), label="file")
        user_file = surface.files[index]
        text = (base / surface.name / user_file.name).read_bytes()
        return surface.name, index, draw(file_mutations(text, user_file.kind, user_file.single))

    @fuzz_settings(examples)
    @given(cases())
    def example(drawn: tuple[str, int, FileMutation]) -> None:
        name, index, mutation = drawn
        surface = by_name[name]
        changed = surface.files[index]
        for path in (case, outside):
            shutil.rmtree(path, ignore_errors=True)
        shutil.copytree(base / name, case)
        apply_file_mutation(case / changed.name, mutation, outside)
        try:
            with example_alarm(example_s):
                result = run_surface(surface, case, out)
        except ExampleTimeout:
            if collect is None:
                raise
            result = (-1, "", "a hang (ExampleTimeout)", None, None)
        tally[f"{name} {mutation.expect.value} exit {result[0]}"] += 1
        problem = judge(mutation, changed, result, baselines[name])
        report = f"{name} {changed.name}: {problem} [{mutation.describe}] stderr: {result[2].strip()[-500:]}"
        if problem and collect is not None:
            collect.append(report)
            return
        assert not problem, report

    explicit = [(s.name, i, m) for s in surfaces for i in range(len(s.files)) for m in every_special(s.files[i].kind)]
    for drawn in explicit:
        example = hypothesis.example(drawn)(example)
    tally["explicit examples"] = len(explicit)
    example()
    return tally


def main_worker(argv: list[str] | None = None) -> int:
    def run(args: argparse.Namespace, work: Path) -> dict:
        collected: list[str] | None = [] if args.collect else None
        tally = fuzz(args.examples, args.example_s, work, collected)
        for line in collected or []:
            print(line)
        return {"outcomes": dict(sorted(tally.items()))}

    def collect_option(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--collect", action="store_true", help="list every broken rule instead of stopping")

    return worker_main(argv, "msflash-user-fuzz-", run, collect_option)


if __name__ == "__main__":
    sys.exit(main_worker())
