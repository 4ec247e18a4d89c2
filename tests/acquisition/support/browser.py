"""Debian's headless Chromium driven by Selenium, for the pages' browser tests (the live page, its views and
camera panel): the binaries, the skip when they are missing, one way to start a driver, small page helpers."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest

RUN = "20260101-000000"
"""The run folder name the pages' tests give the sim rig's run (``sim_run``)."""

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"

needs_chromium = pytest.mark.skipif(
    not (shutil.which(CHROMIUM) and shutil.which(CHROMEDRIVER)),
    reason="Debian's chromium and chromium-driver are not installed (setup.sh installs them)",
)
"""The browser tests' module mark: skipped, saying why, where setup.sh has not installed Chromium."""


def chromium(width: int, height: int) -> object:
    """A headless Chromium driver with a ``width`` × ``height`` window (skips without selenium)."""
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for argument in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        f"--window-size={width},{height}",
        "--no-first-run",
        "--disable-extensions",
    ):
        options.add_argument(argument)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(60)
    return driver


def js(driver, script: str, *args):  # noqa: ANN001, ANN201
    """``script`` run in the page."""
    return driver.execute_script(script, *args)


UNCOVERED = """const box = arguments[0].getBoundingClientRect();
const top = document.elementFromPoint(box.left + box.width / 2, box.top + box.height / 2);
return top !== null && (top === arguments[0] || arguments[0].contains(top));"""


def click(driver, element, timeout_s: float = 30.0) -> None:  # noqa: ANN001
    """Click ``element`` once the page has laid it out on top (a hang guard, not a timing): right after a window
    resize (:func:`shot`) on a loaded machine, a click at the old layout's point landed on another element."""
    js(driver, "arguments[0].scrollIntoView({block: 'center'})", element)
    deadline = time.monotonic() + timeout_s
    while not js(driver, UNCOVERED, element):
        if time.monotonic() > deadline:
            raise AssertionError(f"#{element.get_attribute('id')} stayed covered for {timeout_s} s")
        time.sleep(0.05)
    element.click()


def data(driver, element_id: str, key: str) -> str:  # noqa: ANN001
    """The ``data-key`` attribute of the element ``element_id`` ('' when absent)."""
    return driver.find_element("id", element_id).get_attribute(f"data-{key}") or ""


def shot(driver, tmp_path: Path, name: str) -> None:
    """A screenshot of the whole page (the window made as tall as the page, then back)."""
    size = driver.get_window_size()
    height = js(driver, "return document.documentElement.scrollHeight")
    driver.set_window_size(size["width"], max(size["height"], height + 140))
    driver.save_screenshot(str(tmp_path / f"{name}.png"))
    docs = os.environ.get("MSFLASH_DOCS_SCREENSHOTS")
    if docs and name.startswith("live-"):
        driver.save_screenshot(str(Path(docs) / f"{name}.png"))
    driver.set_window_size(size["width"], size["height"])
