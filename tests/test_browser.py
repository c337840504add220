"""Notebook 00's state explorer in a real JupyterLab, driven by headless Chromium (slow).

The test serves a temporary copy of notebook 00 (profile ``smoke``, outputs cleared) with
JupyterLab on a free localhost port, opens it in Debian's ``chromium`` through Playwright, runs
every cell, moves two sliders and checks that the trace shown in the page is the one
:func:`ibt.views.widgets.trace_view` computes for the new state, on the BT the notebook saved. It
needs ``chromium`` (``apt-get install -y chromium``); CI does not install it, so there it skips.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import nbformat
import pytest

from ibt.bt.json_io import load_json
from ibt.views import widgets

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TOKEN = "ibt-browser-test"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not Path(CHROMIUM).exists(),
                       reason="Debian's chromium is not installed (apt-get install -y chromium); "
                              "the browser test needs it"),
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def notebook_copy(folder: Path) -> Path:
    """Notebook 00 under the smoke profile, without outputs."""
    nb = nbformat.read(ROOT / "notebooks" / "00_quickstart.ipynb", as_version=4)
    params = next(c for c in nb.cells if "parameters" in c.metadata.get("tags", []))
    assert 'profile = "paper"' in params.source and "interactive = True" in params.source
    params.source = params.source.replace('profile = "paper"', 'profile = "smoke"')
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    path = folder / "00_quickstart.ipynb"
    nbformat.write(nb, path)
    return path


@pytest.fixture
def lab(tmp_path):
    """A JupyterLab server on a free port: ``(base_url, smoke_dir)``."""
    notebook_copy(tmp_path)
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k not in ("IBT_PROFILE", "IBT_STATIC")}
    env.update({"IBT_SMOKE_DIR": str(tmp_path / "smoke"),
                "JUPYTER_CONFIG_DIR": str(tmp_path / "jupyter-config"),
                "JUPYTER_RUNTIME_DIR": str(tmp_path / "jupyter-runtime"),
                "JUPYTERLAB_WORKSPACES_DIR": str(tmp_path / "jupyter-workspaces")})
    command = [str(Path(sys.executable).with_name("jupyter")), "lab", "--no-browser",
               f"--port={port}", "--ServerApp.ip=127.0.0.1", f"--IdentityProvider.token={TOKEN}",
               f"--ServerApp.root_dir={tmp_path}", "--LabApp.news_url="]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        command.append("--allow-root")
    log = (tmp_path / "lab.log").open("w")
    server = subprocess.Popen(command, env=env, cwd=tmp_path, stdout=log,
                              stderr=subprocess.STDOUT, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 90
        while True:
            if server.poll() is not None:
                pytest.fail(f"JupyterLab exited: {(tmp_path / 'lab.log').read_text()[-2000:]}")
            try:
                urllib.request.urlopen(f"{base}/api/status?token={TOKEN}", timeout=2)
                break
            except OSError:
                if time.monotonic() > deadline:
                    pytest.fail("JupyterLab did not answer within 90 s")
                time.sleep(0.5)
        yield base, tmp_path / "smoke"
    finally:
        os.killpg(server.pid, signal.SIGTERM)  # the server and its kernels (its own session)
        try:
            server.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
        log.close()


def shown_trace(page) -> tuple[list[float], list[str]]:
    """The state and the trace lines the page shows (whitespace-normalised)."""
    state = json.loads(page.get_attribute(".ibt-state", "data-state"))
    lines = [" ".join(line.split()) for line in page.inner_text(".ibt-trace").splitlines()]
    return state, [line for line in lines if line]


def expected_trace(bt, state) -> list[str]:
    text = widgets.trace_view(bt, state).text()
    return [" ".join(line.split()) for line in text.splitlines()]


def test_slider_moves_the_trace(lab):
    from playwright.sync_api import sync_playwright

    base, smoke = lab
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            page.goto(f"{base}/lab/tree/00_quickstart.ipynb?token={TOKEN}")
            page.wait_for_selector(".jp-Notebook .jp-Cell", timeout=90_000)
            page.wait_for_selector("text=Python 3 (ipykernel) | Idle", timeout=90_000)
            page.click(".lm-MenuBar-itemLabel:text-is('Run')")
            page.click(".lm-Menu-itemLabel:text-is('Run All Cells')")
            page.wait_for_selector(".ibt-trace", timeout=240_000)

            bt = load_json(smoke / "data" / "trees" / "CartPole-v1" / "ppo" / "quickstart.json")
            state, lines = shown_trace(page)
            assert state == pytest.approx([0.0, 0.1, 0.02, -0.3])  # the notebook's state
            assert lines == expected_trace(bt, state)
            seen = {lines[-1]}
            for feature, key, index, bound in (("pole_angle", "End", 2, 0.21),
                                               ("pole_angular_velocity", "Home", 3, -3.5)):
                before = page.get_attribute(".ibt-state", "data-state")
                page.locator(f".ibt-slider-{feature} .noUi-handle").focus()
                page.keyboard.press(key)  # the slider's keyboard control: to its end
                page.wait_for_function(
                    "before => document.querySelector('.ibt-state').dataset.state !== before",
                    arg=before, timeout=60_000)
                state, lines = shown_trace(page)
                assert state[index] == pytest.approx(bound, abs=1e-6)
                assert lines == expected_trace(bt, state)  # the page shows the new tick
                seen.add(lines[-1])
            assert all(line.startswith("decision: push_") for line in seen)
        finally:
            browser.close()
