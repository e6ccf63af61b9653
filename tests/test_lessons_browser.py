"""The lessons in a real browser: JupyterLab on 127.0.0.1, headless Chromium driven by Selenium.

For each solution notebook: open it (the first on its JupyterLab URL, the others in the JupyterLab already
loaded), Run > Run All Cells, wait for the kernel, save; then the last graded check printed PASSED on the page
and the saved notebook holds no error output. Screenshots go to a temporary folder (printed). Skipped when Chromium, its driver or Selenium are missing (Debian:
``apt-get install chromium chromium-driver``; ``pip install selenium``).
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import nbformat
import pytest

from plm_highway.grading.course import check_calls

REPO = Path(__file__).resolve().parents[1]
SOLUTIONS = sorted((REPO / "solutions").glob("*.ipynb"))
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
selenium = pytest.importorskip("selenium", reason="Selenium is not installed")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not (CHROMIUM and CHROMEDRIVER), reason="no Chromium and chromedriver installed")]
RUN_TIMEOUT_S = 900
ACTIVE = ".jp-NotebookPanel:not(.lm-mod-hidden) "  # the notebook in front: other tabs stay in the page


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def jupyterlab(tmp_path_factory):
    root = tmp_path_factory.mktemp("lab")
    for path in SOLUTIONS:
        shutil.copyfile(path, root / path.name)
    settings = tmp_path_factory.mktemp("lab_settings")
    tracker = settings / "@jupyterlab" / "notebook-extension" / "tracker.jupyterlab-settings"
    tracker.parent.mkdir(parents=True)
    tracker.write_text(json.dumps({"windowingMode": "none"}))  # every cell in the page, not only the visible ones
    # No news or update toasts: they would reach for the internet, and a toast that pops up while a menu is open
    # closes the menu, so a Run All or Close All click is lost (seen once in CI: a notebook that never ran).
    notification = settings / "@jupyterlab" / "apputils-extension" / "notification.jupyterlab-settings"
    notification.parent.mkdir(parents=True)
    notification.write_text(json.dumps({"fetchNews": "false", "checkForUpdates": False, "doNotDisturbMode": True}))
    port, token = _free_port(), secrets.token_hex(16)
    env = {key: value for key, value in os.environ.items() if key != "MPLBACKEND"}  # the kernel's inline plots
    env.update(PLM_FAST="1", SDL_VIDEODRIVER="offscreen", JUPYTERLAB_SETTINGS_DIR=str(settings),
               JUPYTERLAB_WORKSPACES_DIR=str(tmp_path_factory.mktemp("lab_workspaces")))  # no tabs from earlier runs
    server = subprocess.Popen([sys.executable, "-m", "jupyter", "lab", "--no-browser", "--ip=127.0.0.1",
                               f"--port={port}", f"--IdentityProvider.token={token}", f"--ServerApp.root_dir={root}",
                               "--ServerApp.open_browser=False", "--allow-root",
                               # window.jupyterapp: the next notebook opens in the running page (see _open)
                               "--LabApp.expose_app_in_browser=True"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                urllib.request.urlopen(f"{base}/api/status?token={token}", timeout=5)
                break
            except OSError:
                if time.monotonic() > deadline or server.poll() is not None:
                    raise RuntimeError("JupyterLab did not start") from None
                time.sleep(0.25)
        yield base, token, root
    finally:
        server.terminate()
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()


@pytest.fixture(scope="module")
def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                     "--window-size=1400,1000"):
        options.add_argument(argument)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    yield driver
    driver.quit()


def _click_menu(driver, menu: str, item: str) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    wait = WebDriverWait(driver, 60)
    wait.until(ec.element_to_be_clickable((By.XPATH, f"//li[contains(@class,'lm-MenuBar-item')][.//div[text()='{menu}']]"))).click()
    wait.until(ec.element_to_be_clickable((By.XPATH, f"//li[contains(@class,'lm-Menu-item')][.//div[text()='{item}']]"))).click()


def _open(driver, base: str, token: str, name: str) -> None:
    """Open the notebook: the first one loads JupyterLab on its URL; later ones open in the running JupyterLab,
    as a student opens the next lesson (loading the whole application again costs seconds of every test)."""
    if not driver.current_url.startswith(f"{base}/lab"):
        driver.get(f"{base}/lab/tree/{name}?token={token}")
        return
    error = driver.execute_script(
        "return window.jupyterapp.commands.execute('docmanager:open', {path: arguments[0]})"
        ".then(() => null, (error) => String(error));", name)
    assert error is None, f"JupyterLab could not open {name}: {error}"


def _texts(driver, selector: str) -> list[str]:
    """The text of every element the CSS selector matches, in one round trip to the browser."""
    return driver.execute_script("return Array.from(document.querySelectorAll(arguments[0]), e => e.innerText);",
                                 selector)


@pytest.fixture(scope="module")
def screenshots(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lesson_screenshots")
    print(f"\nscreenshots: {folder}")
    return folder


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_solution_runs_in_jupyterlab_and_its_last_check_passes(path, jupyterlab, browser, screenshots):
    from selenium.common.exceptions import TimeoutException
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    base, token, root = jupyterlab
    cells = nbformat.read(path, as_version=4).cells
    last_check = max(i for i, cell in enumerate(cells) if cell.cell_type == "code" and check_calls(cell.source))
    check_name = check_calls(cells[last_check].source)[0][1]
    _open(browser, base, token, path.name)

    def opened(driver) -> bool:  # this notebook in front, all its cells on the page, its kernel started
        status = driver.find_element(By.ID, "jp-main-statusbar").text
        return path.name in status and "Idle" in status and len(_texts(driver, ACTIVE + ".jp-Cell")) == len(cells)

    WebDriverWait(browser, 180, poll_frequency=0.5).until(opened)
    started = time.monotonic()

    def prompts(driver) -> list[str]:
        return _texts(driver, ACTIVE + ".jp-CodeCell .jp-InputPrompt")

    def run_started(driver) -> bool:
        return any(prompt.strip() not in ("", "[ ]:") for prompt in prompts(driver))

    def finished(driver):
        if "Idle" not in driver.find_element(By.ID, "jp-main-statusbar").text:
            return False
        shown = prompts(driver)
        # Run All stops at a cell that raises: an idle kernel with unrun cells is finished too
        return bool(shown) and not any("*" in prompt for prompt in shown) and shown[0].strip() not in ("", "[ ]:")

    try:
        _click_menu(browser, "Run", "Run All Cells")
        try:
            WebDriverWait(browser, 30, poll_frequency=0.5).until(run_started)
        except TimeoutException:
            # The click did not reach the notebook (a lost menu click, not the notebook's doing): once more,
            # and if the cells still do not start, fail here rather than after RUN_TIMEOUT_S.
            _click_menu(browser, "Run", "Run All Cells")
            WebDriverWait(browser, 30, poll_frequency=0.5).until(run_started, f"{path.name}: Run All did not start")
        WebDriverWait(browser, RUN_TIMEOUT_S, poll_frequency=0.5).until(finished)
    finally:
        browser.save_screenshot(str(screenshots / f"{path.stem}.png"))
    elapsed_s = time.monotonic() - started
    page_cells = browser.find_elements(By.CSS_SELECTOR, ACTIVE + ".jp-Cell")
    assert len(page_cells) == len(cells)
    browser.execute_script("arguments[0].scrollIntoView();", page_cells[last_check])
    browser.save_screenshot(str(screenshots / f"{path.stem}.png"))
    output = page_cells[last_check].find_element(By.CSS_SELECTOR, ".jp-Cell-outputWrapper").text
    errors_on_page = [e.text[:300] for e in browser.find_elements(By.CSS_SELECTOR, ACTIVE + ".jp-OutputArea-output")
                      if "Error" in e.text or "Traceback" in e.text or "FAILED" in e.text]
    assert not errors_on_page, f"{path.name}: error output on the page: {errors_on_page}"
    assert f"PASSED {check_name}" in output, output
    _click_menu(browser, "File", "Save Notebook")
    deadline = time.monotonic() + 60
    while True:
        saved = nbformat.read(root / path.name, as_version=4)
        if any(cell.get("outputs") for cell in saved.cells if cell.cell_type == "code") or time.monotonic() > deadline:
            break
        time.sleep(0.25)
    _click_menu(browser, "File", "Close All Tabs")
    errors = [(i, out.get("ename")) for i, cell in enumerate(saved.cells) if cell.cell_type == "code"
              for out in cell.outputs if out.output_type == "error"]
    assert not errors, f"{path.name}: error outputs in cells {errors}"
    print(f"{path.name}: all cells ran in {elapsed_s:.0f} s in the browser")
