"""Fixtures the app's tests share: a run of the sim rig (the page tests), a test sequence each test may damage."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from msflash.acquisition.app.live.run_job import SequenceRequest, run_sequence
from msflash.acquisition.session.rig import open_rig
from tests.acquisition.support.browser import RUN
from tests.helpers import write_test_sequence


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One run of the sim rig, as the page's Fire leaves it (copied into each test's runs folder)."""
    runs = tmp_path_factory.mktemp("runs")
    with open_rig("sim") as rig:
        run_sequence(rig, runs / RUN, SequenceRequest())
    return runs / RUN


@pytest.fixture(scope="module")
def base_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A test sequence (tests.helpers.write_test_sequence), written once a module."""
    return write_test_sequence(tmp_path_factory.mktemp("app") / "seq")


@pytest.fixture
def sequence(base_sequence: Path, tmp_path: Path) -> Path:
    """A fresh copy of :func:`base_sequence` for each test (which may damage it)."""
    copy = tmp_path / "seq"
    shutil.copytree(base_sequence, copy)
    return copy
