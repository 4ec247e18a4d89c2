"""Start-up of ``msflash``: ``--help`` and ``--version`` import no numerical or hardware library (issue 18).

What is imported is checked, in a fresh interpreter, never how long it takes (``msflash bench``
measures that, as ratios).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from msflash.acquisition.app import cli

HEAVY = (
    "matplotlib",
    "colour",
    "scipy.stats",
    "dask",
    "gi",
    "OpenImageIO",
    "cvxpy",
    "scipy.linalg",
    "scipy.optimize",
    "aiohttp",
    "selenium",
    "tifffile",
    "rawpy",
    "ome_types",
)
"""Libraries ``msflash --help`` must not import (their packages or anything under them)."""


def imported_after(argv: list[str]) -> set[str]:
    """The modules a fresh interpreter holds after ``main(argv)`` (its SystemExit caught)."""
    code = (
        "import json, sys\n"
        "from msflash.acquisition.app.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "sys.stderr.write(json.dumps(sorted(sys.modules)))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    return set(json.loads(result.stderr.splitlines()[-1]))


def heavy_among(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if any(m == name or m.startswith(name + ".") for name in HEAVY))


@pytest.mark.parametrize("argv", [["--help"], ["--version"], []])
def test_top_level_help_and_version_import_no_heavy_library(argv: list[str]) -> None:
    modules = imported_after(argv)
    assert "msflash.acquisition.app.cli" in modules
    assert heavy_among(modules) == []
    assert "numpy" not in modules
    assert not {m for m in modules if m.startswith("msflash.acquisition.app.cli_")} - {
        "msflash.acquisition.app.cli_common"
    }
    # The lab's commands are listed by name only: finding them imports its package (a docstring), no command module.
    assert {m for m in modules if m.startswith("msflash.lab")} <= {"msflash.lab"}


def test_live_help_imports_no_web_server() -> None:
    modules = imported_after(["live", "--help"])
    assert "msflash.acquisition.app.cli_live" in modules
    assert not {m for m in modules if m == "aiohttp" or m.startswith(("aiohttp.", "msflash.acquisition.app.live"))}


def test_a_commands_help_imports_only_its_own_module() -> None:
    modules = imported_after(["bench", "--help"])
    assert {m for m in modules if m.startswith(("msflash.acquisition.app.cli_", "msflash.lab.cli_"))} == {
        "msflash.acquisition.app.cli_common",
        "msflash.lab.cli_bench",
    }
    assert heavy_among(modules) == []


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_no_commands_help_imports_plotting_colour_statistics_or_dask(name: str) -> None:
    """A command's handler imports what it needs when it runs; its options are known without."""
    modules = imported_after([name, "--help"])
    assert cli.COMMANDS[name][0] in modules
    assert (
        sorted(m for m in modules if m.split(".")[0] in ("matplotlib", "colour", "dask") or m.startswith("scipy.stats"))
        == []
    )


def test_estimate_imports_no_plotting_colour_or_scipy_package(tmp_path) -> None:
    """``estimate`` reads frames (OpenImageIO) and calls scipy's LAPACK and NNLS cores only (processing.scipy_cores)."""
    modules = imported_after(["estimate", str(tmp_path / "absent"), "--json"])
    assert "msflash.acquisition.session.analysis" in modules
    assert {"scipy.linalg", "scipy.optimize"} & modules == set()
    assert [m for m in heavy_among(modules) if not m.startswith(("OpenImageIO", "scipy."))] == []


def subcommand_helps(parser: argparse.ArgumentParser) -> dict[str, str]:
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {action.dest: action.help for action in subparsers._choices_actions}


def test_the_command_table_matches_what_the_modules_register() -> None:
    full = subcommand_helps(cli.build_parser())
    assert list(full.items()) == [(name, summary) for name, (_, summary) in cli.COMMANDS.items()]
    for name, (module_name, _) in cli.COMMANDS.items():
        assert name in subcommand_helps(cli.build_parser([name])), module_name
        registered = argparse.ArgumentParser().add_subparsers()
        __import__(module_name, fromlist=["register"]).register(registered)
        assert name in registered.choices, f"{module_name} does not register '{name}'"


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_each_commands_help_shows_every_option_of_the_full_parser(name: str) -> None:
    def options(parser: argparse.ArgumentParser) -> list[tuple[str, ...]]:
        subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        return [tuple(action.option_strings) or (action.dest,) for action in subparsers.choices[name]._actions]

    assert options(cli.build_parser([name, "--help"])) == options(cli.build_parser())
