"""``msflash study NAME``: the paper's simulation studies (Table 1, Fig. 5) with JSON and a plot.

``table1`` reproduces Table 1 (accuracy vs number of LEDs over 34 cameras and 23 illuminants);
``surfaces`` reproduces Fig. 5 (accuracy vs number of distinct surfaces). The computation lives
in :mod:`processing.study`; this module parses options, runs it (serially, on a local dask
cluster, or on a dask scheduler at an address), prints the result and, with ``--out``, writes
``<name>.json`` and ``<name>.png`` there. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from acquisition.cli_common import UsageError, dumps_json, positive_int, print_json, progress
from processing.ambient import AMBIENT_METHODS

STUDIES = ("table1", "surfaces")
"""Study names accepted by ``msflash study``."""


def _alpha(text: str) -> float | str | list[float]:
    if text in ("auto", "paper"):
        return text
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        raise UsageError(f"--alpha '{text}': expected a number ≥ 0, a comma-separated list, 'auto' or 'paper'") from None
    if not all(value >= 0 for value in values):
        raise UsageError(f"--alpha {text}: expected values ≥ 0")
    return values[0] if len(values) == 1 else values


def _counts(text: str) -> list[int]:
    try:
        values = [int(part) for part in text.split(",")]
    except ValueError:
        raise UsageError(f"'{text}': expected comma-separated whole numbers") from None
    if not values or min(values) < 1:
        raise UsageError(f"'{text}': expected whole numbers ≥ 1")
    return values


@contextmanager
def _mapper(scheduler: str, workers: int | None) -> Iterator[Callable[[Callable[..., Any], Sequence[Any]], Any] | None]:
    """A map function running jobs serially (``none``), on a local dask cluster (``local``) or at an address."""
    if scheduler == "none":
        yield None
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        if scheduler == "local":
            progress("dask.distributed is not installed; running serially")
            yield None
            return
        raise UsageError(f"--scheduler {scheduler}: dask.distributed is not installed (pip install msflash[study])") from None
    cluster = None
    if scheduler == "local":
        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0")
        client = Client(cluster)
        progress(f"dask: local cluster with {n} workers")
    else:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as err:
            raise UsageError(f"--scheduler {scheduler}: cannot connect ({err}); expected a dask scheduler address") from None
        progress(f"dask: scheduler {scheduler}")

    def mapper(function: Callable[..., Any], items: Sequence[Any]) -> Iterator[Any]:
        futures = client.map(function, list(items), pure=False)
        for future in futures:  # in order, so results stay aligned with the cameras
            yield future.result()

    try:
        yield mapper
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _run(args: argparse.Namespace) -> int:
    if args.name not in STUDIES:
        raise UsageError(f"study '{args.name}': unknown; expected one of {', '.join(STUDIES)}")
    alpha = args.alpha
    alpha_units = args.alpha_units
    if alpha == "paper":
        if args.solver != "roughness":
            raise UsageError("--alpha paper is the authors' sweep of eq. 6; expected --solver roughness")
        from processing.study.table1 import PAPER_ALPHAS

        alpha, alpha_units = (list(PAPER_ALPHAS) if args.name == "table1" else 0.06), "paper"
    if isinstance(alpha, list) and args.name != "table1":
        raise UsageError("--alpha: a sweep is only for table1; expected one value")
    if alpha_units == "paper" and args.solver != "roughness":
        raise UsageError("--alpha-units paper is the authors' eq. 6; expected --solver roughness")
    out = Path(args.out) if args.out else None
    if out is not None:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise UsageError(f"--out {out}: cannot create the folder ({err})") from None

    with _mapper(args.scheduler, args.workers) as mapper:
        if args.name == "table1":
            from processing.study.table1 import run_table1

            result = run_table1(n_leds_list=args.leds, method=args.solver, alpha=alpha, cameras=args.cameras,
                                illuminants=args.illuminants, alpha_units=alpha_units, progress=progress,
                                map_function=mapper)
        else:
            from processing.study.surfaces import run_surfaces

            result = run_surfaces(draws=args.draws, method=args.solver, alpha=alpha, cameras=args.cameras,
                                  illuminants=args.illuminants, alpha_units=alpha_units, seed=args.seed,
                                  progress=progress, map_function=mapper)
    result = json.loads(dumps_json(result))  # plain JSON types (numpy scalars, tuples) from here on
    if out is not None:
        json_path = out / f"{args.name}.json"
        json_path.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
        png_path = out / f"{args.name}.png"
        (_plot_table1 if args.name == "table1" else _plot_surfaces)(result, png_path)
        result["files"] = {"json": str(json_path), "png": str(png_path)}
        progress(f"wrote {json_path} and {png_path}")
    if args.json:
        print_json(result)
    else:
        print(_table1_text(result) if args.name == "table1" else _surfaces_text(result))
    return 0


_ROWS = (
    ("pixel_rmse", "Pixel RMSE (x1e-2)"),
    ("xy_error", "CIE xy error (x1e-2)"),
    ("spectrum_rmse", "Spectrum RMSE"),
    ("multispectral_rmse", "Multispectral (LED fit)"),
)


def _table1_text(result: dict[str, Any]) -> str:
    config = result["config"]
    lines = [f"Table 1: {config['method']} alpha={config['alpha']} ({config['alpha_units']}), "
             f"{config['n_cameras']} cameras x {config['n_illuminants']} illuminants, {result['elapsed_s']:.1f} s",
             f"{'# LEDs':26s}" + "".join(f"{n:>15d}" for n in result["n_leds"])]
    for key, label in _ROWS:
        paper = result["paper"].get(key, [])
        cells = "".join(f"{ours:>8.3f} ({p:<4g})" for ours, p in zip(result[key], paper, strict=False))
        lines.append(f"{label:26s}{cells}")
    lines.append("(ours, paper in brackets)")
    if result.get("failures"):
        lines.append(f"{result['failures']} estimates failed (SolverError) and were left out")
    return "\n".join(lines)


def _surfaces_text(result: dict[str, Any]) -> str:
    config = result["config"]
    lines = [f"Fig. 5: {config['n_leds']} LEDs, {config['method']} alpha={config['alpha']}, {config['n_cameras']} "
             f"cameras x {len(config['illuminants_xy'])} illuminants, {config['draws']} draws, "
             f"{result['elapsed_s']:.1f} s",
             f"{'surfaces':>9s} {'spectrum RMSE':>14s} {'std':>7s} {'pixel RMSE x1e-2':>17s}"]
    for count, mean, std, pixel in zip(result["counts"], result["spectrum_rmse"], result["spectrum_rmse_std"],
                                       result["pixel_rmse"], strict=True):
        if mean is None:
            lines.append(f"{count:>9d} {'failed':>14s}   (estimate_ambient refused or failed for every draw)")
            continue
        lines.append(f"{count:>9d} {mean:>14.4f} {std:>7.4f} {pixel:>17.4f}")
    lines.append(f"bound (direct LED fit of the truth): {result['bound']:.4f}")
    return "\n".join(lines)


def _pyplot():  # noqa: ANN202 - matplotlib imported lazily with the non-interactive backend
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_table1(result: dict[str, Any], path: Path) -> None:
    plt = _pyplot()
    figure, axes = plt.subplots(1, 4, figsize=(15, 3.6))
    counts = result["n_leds"]
    for axis, (key, label) in zip(axes, _ROWS, strict=True):
        axis.plot(counts, result[key], "o-", label="msflash")
        paper = result["paper"].get(key)
        if paper:
            axis.plot(counts[:len(paper)], paper, "s--", label="paper")
        axis.set_title(label, fontsize=10)
        axis.set_xlabel("# LEDs")
        axis.set_xticks(counts)
        axis.grid(True, alpha=0.3)
    axes[0].legend()
    config = result["config"]
    figure.suptitle(f"Table 1 — {config['method']}, alpha {config['alpha']} ({config['alpha_units']})", fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def _plot_surfaces(result: dict[str, Any], path: Path) -> None:
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(5, 3.6))
    def numbers(values: list[Any]) -> list[float]:  # JSON null (all estimates failed) → NaN, not drawn
        return [float("nan") if value is None else value for value in values]

    axis.errorbar(result["counts"], numbers(result["spectrum_rmse"]), yerr=numbers(result["spectrum_rmse_std"]), fmt="o-",
                  capsize=3, label="estimate (mean ± std over draws)")
    axis.axhline(result["bound"], color="k", linestyle="--", label="direct LED fit")
    axis.set_xlabel("distinct surfaces")
    axis.set_ylabel("spectrum RMSE")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``msflash study``."""
    study = subparsers.add_parser("study", help="the paper's simulation studies (table1: Table 1; surfaces: Fig. 5)")
    study.add_argument("name", metavar="NAME", help=f"the study: {', '.join(STUDIES)}")
    study.add_argument("--out", metavar="DIR", help="write NAME.json and NAME.png to this folder")
    study.add_argument("--json", action="store_true", help="print the result as one JSON object")
    study.add_argument("--solver", default="tikhonov", choices=sorted(AMBIENT_METHODS),
                       help="ambient estimator (default: tikhonov, the app's default)")
    study.add_argument("--alpha", default="auto", type=_alpha,
                       help="roughness weight: a number, a comma-separated sweep (table1: best per metric), 'auto', "
                            "or 'paper' (the authors' logspace(-3,1,10) sweep of eq. 6; --solver roughness)")
    study.add_argument("--alpha-units", default="dimensionless", choices=("dimensionless", "paper"),
                       help="'paper': alpha is the authors' eq.-6 weight (--solver roughness)")
    study.add_argument("--leds", type=_counts, default=[3, 4, 5, 6, 7], help="table1: LED counts (default 3,4,5,6,7)")
    study.add_argument("--cameras", type=positive_int, default=None, help="use the first N of the 34 cameras")
    study.add_argument("--illuminants", type=positive_int, default=None,
                       help="use N of the 23 feasible illuminants, spread over the grid")
    study.add_argument("--draws", type=positive_int, default=10, help="surfaces: draws per count (default 10)")
    study.add_argument("--seed", type=int, default=0, help="surfaces: random seed of the draws")
    study.add_argument("--scheduler", default="local",
                       help="'local' (a local dask cluster, default), 'none' (serial, in this process) or a dask scheduler ADDRESS")
    study.add_argument("--workers", type=positive_int, default=None, help="workers of --scheduler local (default: CPUs)")
    study.set_defaults(handler=_run)
