"""``msflash bench --part many``: ``msflash estimate`` over many sequences, 1 against 2 dask workers.

Eight sequences of the benchmark world (:func:`lab.bench.processing.benchmark_world`, 512 × 640 RGB,
7 LEDs) are written to a temporary folder; two local dask clusters, of one and of two worker processes,
are started side by side and warmed up; then, round after round, the sequences' estimates
(:func:`acquisition.session.many.estimate_record`, what ``msflash estimate DIR`` runs) are mapped
serially in this process (``--scheduler none``), on the one-worker cluster and on the two-worker one.
``speedup_1_to_2_workers`` is the median over rounds of the one-worker time ÷ the two-worker time
(runs seconds apart, so the ratio holds while other load comes and goes), with its spread;
``two_workers_over_serial`` the two-worker time ÷ the serial time (above 1: dask did not pay). The
cluster start (2–3 s, more under load) is left out: it is paid once per command. Each worker's image
passes already use two threads (``processing.moment_products.DEFAULT_WORKERS``), so on two cores the ideal
is below 2. The records of the three are checked equal (``identical``).
"""

from __future__ import annotations

import os
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
from msflash.acquisition.sequence.writer import SequenceWriter
from msflash.acquisition.session.dask_map import dask_mapper
from msflash.acquisition.session.many import estimate_record
from msflash.acquisition.session.one_sequence import EstimateSettings


def write_bench_sequences(out: Path, count: int, height: int, width: int) -> list[str]:
    """``count`` copies of the benchmark world's sequence under ``out`` (photon units); their folders."""
    from msflash.lab.bench.processing import benchmark_world

    world = benchmark_world(height, width)
    spec = world["spec"]
    leds, camera = world["leds"], world["camera"]
    sequence_camera = SequenceCamera(
        model="bench-render",
        serial=None,
        pixel_format="RGB16",
        cfa=None,
        black_level=spec.black_level,
        white_level=spec.white_level,
        responsivity={name: camera.column(name) for name in ("R", "G", "B")},
    )
    sequence_leds = [SequenceLed(name, leds.column(name)) for name in leds.names]
    k = len(sequence_leds)
    exposure = 1.0 / spec.ambient_scale
    folders = []
    for index in range(count):
        folder = out / f"{index:03d}"
        with SequenceWriter(
            folder,
            wavelengths_nm=leds.grid.wavelengths_nm,
            spectral_unit="photons",
            camera=sequence_camera,
            leds=sequence_leds,
        ) as writer:
            writer.add_frame(world["frames"][0], "ambient", [0.0] * k, exposure_us=exposure)
            for led, frame in enumerate(world["frames"][1:]):
                writer.add_frame(frame, "led", [float(led == i) for i in range(k)], exposure_us=exposure)
        folders.append(str(folder))
    return folders


def many_bench(count: int = 8, height: int = 512, width: int = 640, rounds: int = 9) -> dict[str, Any]:
    """The 1 → 2 worker speed-up of estimates over ``count`` sequences (module notes), in this one run.

    Returns
    -------
    dict
        ``speedup_1_to_2_workers`` (median of the per-round ratios) and its ``spread`` (min, max), the
        median seconds on each cluster, whether the two clusters' records are identical, and what was run.
    """
    settings = EstimateSettings()
    arms = ("serial", "one", "two")
    with tempfile.TemporaryDirectory(prefix="msflash-bench-many-") as scratch:
        jobs = [(folder, settings) for folder in write_bench_sequences(Path(scratch), count, height, width)]
        with ExitStack() as stack:
            mappers = {
                "serial": stack.enter_context(dask_mapper("none")),
                "one": stack.enter_context(dask_mapper("local", 1)),
                "two": stack.enter_context(dask_mapper("local", 2)),
            }
            records = {arm: list(mappers[arm](estimate_record, jobs)) for arm in arms}  # also the warm-up
            failed = [record.error for arm in arms for record in records[arm] if record.error is not None]
            if failed:
                return {"failed": failed[0]}
            times: dict[str, list[float]] = {arm: [] for arm in arms}
            for _ in range(rounds):
                for arm in arms:
                    start = time.perf_counter()
                    list(mappers[arm](estimate_record, jobs))
                    times[arm].append(time.perf_counter() - start)
    speedups = np.array(times["one"]) / np.array(times["two"])
    over_serial = np.array(times["two"]) / np.array(times["serial"])
    identical = all(
        repr(a.payload) == repr(b.payload) == repr(c.payload)
        for a, b, c in zip(records["serial"], records["one"], records["two"], strict=True)
    )
    return {
        "speedup_1_to_2_workers": float(np.median(speedups)),
        "spread": [float(speedups.min()), float(speedups.max())],
        "two_workers_over_serial": float(np.median(over_serial)),
        "two_workers_over_serial_spread": [float(over_serial.min()), float(over_serial.max())],
        "seconds_serial": float(np.median(times["serial"])),
        "seconds_1_worker": float(np.median(times["one"])),
        "seconds_2_workers": float(np.median(times["two"])),
        "identical": identical,
        "what": f"msflash estimate over {count} sequences of {height}x{width} RGB, 7 LEDs, {rounds} interleaved "
        f"rounds: in this process (serial), on local dask clusters of 1 and of 2 worker processes; "
        f"{os.cpu_count()} CPUs (shared: other load shows in the spreads)",
    }
