"""Fixtures the app's page tests share (a test sequence each test may damage: tests/acquisition/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from msflash.acquisition.app.live.run_job import SequenceRequest, run_sequence
from msflash.acquisition.session.rig import open_rig
from tests.acquisition.support.browser import RUN


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One run of the sim rig, as the page's Fire leaves it (copied into each test's runs folder)."""
    runs = tmp_path_factory.mktemp("runs")
    with open_rig("sim") as rig:
        run_sequence(rig, runs / RUN, SequenceRequest())
    return runs / RUN
