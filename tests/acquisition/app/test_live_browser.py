"""``msflash live`` in a real browser: Debian's headless Chromium driven by Selenium (issue 23).

The page is loaded from a :class:`LiveServer` on a sim rig; frames must arrive, a slider moved with the
keyboard must change the level the booth emulator holds (read at the far end of the pty), a reload must
keep it, and the fire button must leave a run folder with ``msflash run``'s files and show its spectrum.
Each test leaves a screenshot in its tmp dir.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.acquisition.support.browser import chromium, needs_chromium
from tests.acquisition.support.live import emulator_levels, live_server, wait_until

pytestmark = needs_chromium


@pytest.fixture
def browser() -> Iterator[object]:
    driver = chromium(1320, 1500)
    try:
        yield driver
    finally:
        driver.quit()  # type: ignore[attr-defined]


def frames_shown(driver) -> int:
    return int(driver.find_element("id", "frame-count").get_attribute("data-frames") or 0)


def test_frames_arrive_a_slider_sets_the_booth_and_a_reload_keeps_it(tmp_path: Path, browser) -> None:
    from selenium.webdriver.common.keys import Keys

    with live_server(tmp_path / "runs") as server:
        browser.get(f"http://127.0.0.1:{server.port}/")
        wait_until(lambda: frames_shown(browser) >= 3, "three live frames on the page")
        image = browser.find_element("id", "live")
        wait_until(lambda: browser.execute_script("return arguments[0].naturalWidth", image) == 640, "a 640-px frame")
        histogram = browser.find_element("id", "hist-g").get_attribute("points")
        assert histogram and len(histogram.split()) == 64
        browser.save_screenshot(str(tmp_path / "live-frames.png"))

        slider = browser.find_element("id", "led-3")  # led520
        slider.click()  # focus (a click may also move it: the level is read back, not assumed)
        slider.send_keys(Keys.HOME)
        for _ in range(20):
            slider.send_keys(Keys.ARROW_RIGHT)
        wait_until(lambda: abs(emulator_levels(server)[3] - 0.20) < 1e-3, "the booth emulator's led520 at 20 %")
        assert emulator_levels(server)[:3] == (0.0, 0.0, 0.0)
        booth_text = browser.find_element("id", "led-3-booth")
        wait_until(lambda: booth_text.text == "booth 20%", "the booth's read-back level on the page")
        browser.save_screenshot(str(tmp_path / "live-slider.png"))

        browser.refresh()  # the state lives in the server: the reload loses nothing, the LEDs stay on
        wait_until(lambda: frames_shown(browser) >= 1, "frames after the reload")
        assert browser.find_element("id", "led-3").get_attribute("value") == "20"
        assert abs(emulator_levels(server)[3] - 0.20) < 1e-3
        browser.save_screenshot(str(tmp_path / "live-reloaded.png"))
        browser.get("about:blank")  # the last page goes away: the LEDs go off
        wait_until(lambda: emulator_levels(server) == (0.0,) * 7, "LEDs off once no page watches")


def test_the_fire_button_leaves_a_run_and_shows_its_spectrum(tmp_path: Path, browser) -> None:
    runs = tmp_path / "runs"
    with live_server(runs) as server:
        browser.get(f"http://127.0.0.1:{server.port}/")
        wait_until(lambda: frames_shown(browser) >= 1, "a live frame")
        browser.find_element("id", "fire").click()
        job = browser.find_element("id", "job")
        wait_until(lambda: job.get_attribute("data-status") == "done", "the sequence to finish", timeout_s=240)
        run = job.get_attribute("data-run")
        folder = runs / run
        for name in (
            "sequence/sequence.json",
            "estimate.json",
            "flash-matching.json",
            "flash-complementary.json",
            "ambient.png",
            "matching.png",
            "complementary.png",
            "flash-capture.png",
            "spectra.png",
            "report.html",
            "run.json",
        ):
            assert (folder / name).is_file(), name
        assert len(list((folder / "sequence" / "frames").iterdir())) == 9  # ambient, 7 LEDs, flash
        assert len(browser.find_elements("css selector", "#job-steps li.landed")) == 9
        # matplotlib's SVG (issue 33): the band (clipped to the axes when it leaves them), the mixes as the report.
        wait_until(lambda: browser.find_elements("css selector", "#charts svg g#band"), "the band")
        assert browser.find_elements("css selector", "#charts svg g#mix-complementary-flash")
        assert browser.find_elements("css selector", "#charts svg g#mix-matching-flash")
        previews = browser.find_elements("css selector", "#previews img")
        assert len(previews) == 4
        wait_until(
            lambda: all(browser.execute_script("return arguments[0].naturalWidth", img) > 0 for img in previews),
            "the previews to load",
        )
        assert run in browser.find_element("id", "run-list").text
        browser.save_screenshot(str(tmp_path / "live-sequence.png"))

        browser.get(f"http://127.0.0.1:{server.port}/runs/{run}/")  # the run's report: what `msflash run` writes
        assert browser.current_url.endswith(f"/runs/{run}/files/report.html")
        assert "spectrum RMSE against the true ambient" in browser.page_source
        images = browser.find_elements("css selector", "img")
        assert images and all(browser.execute_script("return arguments[0].naturalWidth", i) > 0 for i in images)
        browser.save_screenshot(str(tmp_path / "live-report.png"))
