"""The control panel end to end in a real headless Chromium (Debian's chromium + chromedriver, via Selenium)."""

import shutil
import time

import av
import pytest
from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from conftest import PanelProcess

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


@pytest.fixture
def browser(tmp_path):
    options = Options()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1400,1000"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    yield driver
    driver.quit()


IMAGE_HASH = """
const img = document.getElementById(arguments[0]);
if (!img.naturalWidth) return null;
const c = document.createElement('canvas'); c.width = img.naturalWidth; c.height = img.naturalHeight;
const g = c.getContext('2d'); g.drawImage(img, 0, 0);
const d = g.getImageData(0, 0, c.width, c.height).data; let h = 0;
for (let i = 0; i < d.length; i += 97) h = (h * 31 + d[i]) >>> 0;
return h;
"""


def test_panel_in_a_real_browser(tmp_path, browser):
    with PanelProcess(["run", "--output", "none", "--fps", "30", "--record-to", "rec.mkv"], tmp_path) as panel:
        proc = panel.proc
        browser.get(panel.url)
        wait = WebDriverWait(browser, 20)
        assert "antiscatter" in browser.title
        # the live image arrives and keeps changing
        first = wait.until(lambda d: d.execute_script(IMAGE_HASH, "input"))
        wait.until(lambda d: d.execute_script(IMAGE_HASH, "input") not in (None, first))
        wait.until(lambda d: d.execute_script(IMAGE_HASH, "pattern") is not None)
        # the figures change (read in one script call: the table is redrawn twice a second)
        stat = lambda d, key: d.execute_script(  # noqa: E731
            "const e = document.getElementById('stat-' + arguments[0]); return e ? e.textContent : null;", key)
        before = int(wait.until(lambda d: stat(d, "frames")))
        wait.until(lambda d: int(stat(d, "frames") or 0) > before)
        # Record start, then stop: a valid file
        browser.find_element(By.ID, "record").click()
        wait.until(lambda d: d.find_element(By.ID, "status").text == "recording")
        wait.until(lambda d: stat(d, "recording") == "rec.mkv")
        time.sleep(1.0)
        browser.find_element(By.ID, "record").click()
        wait.until(lambda d: d.find_element(By.ID, "status").text == "recording stopped")
        # what runs, at the top
        assert browser.find_element(By.ID, "info-source").text == "sim"
        assert browser.find_element(By.ID, "info-detector").text == "contrast"
        assert browser.find_element(By.ID, "info-frame").text == "800 x 600 px"
        # a control: a value out of range is refused with its message on the page, one in range applies
        field = wait.until(lambda d: d.find_element(By.ID, "control-sensitivity"))
        field.clear()
        field.send_keys("99")
        browser.find_element(By.ID, "set-sensitivity").click()
        wait.until(lambda d: d.find_element(By.ID, "status").text == "detector k: got '99', allowed 2 to 14")
        assert browser.find_element(By.ID, "status").get_attribute("class") == "error"
        field.clear()
        field.send_keys("6")
        browser.find_element(By.ID, "set-sensitivity").click()
        wait.until(lambda d: d.find_element(By.ID, "status").text.startswith("contrast k 6 from the next frame"))
        assert browser.find_element(By.ID, "status").get_attribute("class") == ""
        frames = int(stat(browser, "frames"))
        wait.until(lambda d: int(stat(d, "frames") or 0) > frames + 5)  # the run goes on with it
        # the chart is drawn: pixels on the canvas
        assert browser.execute_script(
            "const c = document.getElementById('chart'); const d = c.getContext('2d').getImageData(0, 0, c.width, "
            "c.height).data; for (let i = 3; i < d.length; i += 4) if (d[i]) return true; return false;")
        # Stop ends the run
        browser.find_element(By.ID, "stop").click()
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "stopped by panel" in out
    with av.open(str(tmp_path / "rec.mkv")) as container:
        assert sum(1 for _ in container.decode(video=0)) >= 15
