"""The live page's camera in headless Chromium at 1024 px and 1920 px (issue 33): ROI, binning and pixel format set
from the page (the frame size follows, a refused value shows the camera's reason), a camera that fails mid-stream
(its reason large on the greyed image, LEDs off, reconnect), and the charts' series inside their plot areas by
geometry.

A real sim rig and its booth emulator on a pty. ``MSFLASH_DOCS_SCREENSHOTS=DIR`` also leaves
``DIR/live-<width>-camera.png`` and ``DIR/live-<width>-camera-error.png``.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.acquisition.support.browser import RUN, chromium, click, data, js, needs_chromium, shot
from tests.acquisition.support.live import emulator_levels, live_server, wait_until

pytestmark = needs_chromium


@pytest.fixture(params=[(1024, 900), (1920, 1200)], ids=["1024px", "1920px"])
def browser(request: pytest.FixtureRequest) -> Iterator[object]:
    driver = chromium(*request.param)
    try:
        yield driver
    finally:
        driver.quit()  # type: ignore[attr-defined]


def frame_size(driver) -> str:
    return data(driver, "frame-size", "size")


def set_roi(driver, x: int, y: int, w: int, h: int) -> None:
    for key, value in zip("xywh", (x, y, w, h)):
        field = driver.find_element("id", f"roi-{key}")
        field.clear()
        field.send_keys(str(value))
    click(driver, driver.find_element("id", "roi-apply"))


def test_roi_binning_and_pixel_format_from_the_page(tmp_path: Path, browser) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.select import Select

    driver = browser
    width = js(driver, "return window.innerWidth")
    with live_server(tmp_path / "runs") as server:
        driver.get(f"http://127.0.0.1:{server.port}/")
        wait_until(lambda: frame_size(driver) == "112x106", "the sensor's full frame")
        assert driver.find_element("id", "camera-format").text.startswith("BayerRG12 · 112 × 106")
        assert "in steps of 8" in driver.find_element("id", "roi-w").get_attribute("title")

        set_roi(driver, 8, 4, 32, 20)
        wait_until(lambda: frame_size(driver) == "32x20", "the ROI's frame size")
        assert server.rig.camera.info.width == 32 and data(driver, "camera-format", "width") == "32"
        image = driver.find_element("id", "live")
        ActionChains(driver).move_to_element_with_offset(image, 5, 5).perform()  # the readout follows the ROI
        wait_until(lambda: "row" in driver.find_element("id", "readout").text, "a readout of the ROI")
        assert int(driver.find_element("id", "readout").text.split("row ")[1].split(",")[0]) < 20

        Select(driver.find_element("id", "binning")).select_by_value("2x2")
        wait_until(lambda: frame_size(driver) == "56x52", "the binned frame (the ROI reset to the binned sensor)")

        Select(driver.find_element("id", "pixel-format")).select_by_value("BayerRG8")
        wait_until(lambda: data(driver, "camera-format", "pixel-format") == "BayerRG8", "the 8-bit format")
        before = int(data(driver, "frame-count", "frames"))
        wait_until(lambda: int(data(driver, "frame-count", "frames")) > before + 2, "frames in the 8-bit format")
        assert server._last_raw is not None and server._last_raw.pixels.dtype.name == "uint8"
        ActionChains(driver).move_to_element_with_offset(image, 7, 7).perform()
        wait_until(lambda: data(driver, "readout", "values"), "a readout in the 8-bit format")

        set_roi(driver, 0, 0, 50, 20)  # refused: Width in steps of 8
        message = driver.find_element("id", "format-message")
        wait_until(lambda: message.get_attribute("data-refused") == "1", "the refusal")
        assert "Width 50 refused; expected a whole number in 8 … 56 in steps of 8" in message.text
        assert frame_size(driver) == "56x52" and server.state.error is None  # nothing changed, nothing switched off
        assert js(driver, "return document.documentElement.scrollWidth") <= width
        js(driver, "window.scrollTo(0, 0)")
        shot(driver, tmp_path, f"live-{width}-camera")


def test_a_camera_that_fails_mid_stream_shows_its_reason_switches_the_leds_off_and_reconnects(
    tmp_path: Path, browser
) -> None:
    from msflash.acquisition.app.live.server import TOKEN_HEADER
    from tests.acquisition.app.test_live_http import request

    driver = browser
    width = js(driver, "return window.innerWidth")
    with live_server(tmp_path / "runs") as server:
        driver.get(f"http://127.0.0.1:{server.port}/")
        wait_until(lambda: int(data(driver, "frame-count", "frames") or 0) >= 3, "live frames")
        base = f"http://127.0.0.1:{server.port}"
        assert (
            request("POST", base + "/api/levels", {TOKEN_HEADER: server.token}, {"channel": 3, "level": 0.5})[0] == 200
        )
        wait_until(lambda: emulator_levels(server)[3] > 0.4, "led522 lit")

        server.rig.camera.unplug("USB cable pulled")  # the twin of a camera that goes away mid-stream
        wait_until(lambda: js(driver, "return document.body.dataset.connection") == "error", "the camera error")
        box = driver.find_element("id", "disconnected")
        assert box.is_displayed() and "Camera error" in box.text and "Disconnected" not in box.text
        assert "USB cable pulled" in box.text and "LEDs switched off" in box.text
        assert js(driver, "return document.body.dataset.errorSource") == "camera"
        assert js(driver, "return getComputedStyle(arguments[0]).filter", driver.find_element("id", "live")).startswith(
            "grayscale"
        )
        assert emulator_levels(server) == (0.0,) * 7  # at the booth's end of the pty
        reconnect = driver.find_element("id", "reconnect")
        assert reconnect.is_displayed()
        js(driver, "window.scrollTo(0, 0)")
        shot(driver, tmp_path, f"live-{width}-camera-error")

        click(driver, reconnect)  # still unplugged: the retry fails, the error stays, saying why
        wait_until(lambda: reconnect.get_attribute("data-result") == "failed", "a failed retry")
        assert js(driver, "return document.body.dataset.connection") == "error"
        assert "USB cable pulled" in driver.find_element("id", "disconnected-reason").text
        server.rig.camera.replug()
        shown = int(data(driver, "frame-count", "frames"))
        # The stream's own retry (every second) may clear the error and hide the button before a click lands (a
        # loaded machine: "element has zero size"); the button's handler is pressed either way and must succeed.
        js(driver, "arguments[0].click()", reconnect)
        wait_until(lambda: reconnect.get_attribute("data-result") == "ok", "a retry that succeeds")
        wait_until(lambda: js(driver, "return document.body.dataset.connection") == "live", "live again")
        wait_until(lambda: int(data(driver, "frame-count", "frames")) > shown + 2, "frames again")
        assert not driver.find_element("id", "disconnected").is_displayed()


CLIPPED = """
const out = [];
for (const svg of document.querySelectorAll('#charts svg')) {
  const area = svg.querySelector('g[id^=axes_] > g[id^=patch_] path').getBoundingClientRect();
  for (const group of svg.querySelectorAll('g[id=band], g[id=estimate], g[id=truth], g[id^=mix-]')) {
    for (const shape of group.querySelectorAll(':scope > path, :scope > g > use')) {  // a fill: a <use> of its <defs>
      const box = shape.getBoundingClientRect();
      out.push({id: group.id, area: [area.left, area.top, area.right, area.bottom],
                box: [box.left, box.top, box.right, box.bottom]});
    }
  }
}
return out;
"""


def test_every_series_of_the_charts_lies_inside_its_plot_area(tmp_path: Path, sim_run: Path, browser) -> None:
    """By the drawn geometry (each series' rendered bounding box within its axes' background, 1.5 px of slack),
    not by the presence of a clip-path: a band that runs past the axes would be cut off, and the reader would
    not know."""
    driver = browser
    runs = tmp_path / "runs"
    shutil.copytree(sim_run, runs / RUN)
    with live_server(runs) as server:
        driver.get(f"http://127.0.0.1:{server.port}/")
        wait_until(lambda: driver.find_elements("css selector", "#charts svg g#band"), "the charts")
        boxes = js(driver, CLIPPED)
    ids = {entry["id"] for entry in boxes}
    assert {"band", "estimate", "truth"} <= ids and any(i.startswith("mix-") for i in ids)
    for entry in boxes:
        (x0, y0, x1, y1), (bx0, by0, bx1, by1) = entry["area"], entry["box"]
        slack = 1.5
        assert x0 - slack <= bx0 and bx1 <= x1 + slack and y0 - slack <= by0 and by1 <= y1 + slack, entry
