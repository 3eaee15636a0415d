"""The HTML report (`snakemake --report`) of the smoke run, opened in a real headless Chromium: it loads
offline, asks for nothing outside the file, and every figure shows when clicked, at its full size.

A screenshot of a figure in the report is written to results/report_screenshot.png (the README shows
a copy, docs/report_screenshot.png)."""

import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO
from headless_chromium import Chromium, find_chromium

pytestmark = pytest.mark.slow

#: URL schemes a self-contained report may load: itself and what it embeds.
LOCAL_SCHEMES = ("file:", "data:", "blob:", "about:")
#: The figure shown in the screenshot for the README.
SCREENSHOT_FIGURE = "results/report/figures/topview.png"
SCREENSHOT = REPO / "results" / "report_screenshot.png"

APP_READY = ("document.querySelector('#loading-screen').style.display === 'none'"
             " && document.querySelector('#app').children.length > 0")
NO_BROKEN_IMAGE = "[...document.images].every(i => i.complete && i.naturalWidth > 0)"


def _needs_chromium():
    if find_chromium() is None:
        if os.environ.get("CI", "").lower() == "true":
            raise RuntimeError("CI: Chromium is missing (scripts/system_packages.sh browser installs it)")
        pytest.skip("no Chromium (Debian: apt-get install chromium, or bash scripts/system_packages.sh browser)")


@pytest.fixture(scope="module")
def report_html(smoke_run) -> Path:
    _needs_chromium()
    out = smoke_run / "results" / "report_browser.html"
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--configfile", "config_smoke.yaml", "--report",
                           str(out.relative_to(smoke_run))], cwd=smoke_run, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", head[16:24])


def _click(browser: Chromium, selector_js: str, what: str) -> None:
    """Click the element a JavaScript expression finds, as a user's click would."""
    found = browser.evaluate(f"(() => {{ const el = {selector_js}; if (!el) return false; el.click(); return true }})()")
    assert found, f"not in the report's page: {what}"


def _show_figure(browser: Chromium, category: str, path: str) -> None:
    """Home, the category in the menu, then the figure's eye button."""
    _click(browser, "document.querySelector('nav ol a')", "the home button")
    _click(browser, f"[...document.querySelectorAll('nav a')].find(a => a.textContent.trim() === {category!r})",
           f"menu entry {category}")
    _click(browser, f"[...document.querySelectorAll('nav tr')].find(r => r.cells[0]"
                    f" && r.cells[0].textContent.trim() === {path!r})?.querySelector('a[iconname=eye]')",
           f"the view button of {path}")


def test_report_in_chromium(report_html, smoke_run, tmp_path):
    with Chromium(tmp_path / "profile") as browser:
        browser.open(report_html.as_uri())
        browser.wait_for(APP_READY, "the report's app")
        # Every image result of the report, by category, and the figures the workflow wrote.
        categories = browser.evaluate("categories")
        shown = {p: c for c, subs in categories.items() for paths in subs.values() for p in paths
                 if p.endswith((".png", ".svg", ".jpg", ".jpeg"))}
        written = {str(p.relative_to(smoke_run)) for p in (smoke_run / "results/report/figures").glob("*.png")}
        if (smoke_run / "results/noise/noise.png").exists():
            written.add("results/noise/noise.png")
        assert set(shown) == written
        for path, category in sorted(shown.items()):
            _show_figure(browser, category, path)
            main_img = (f"[...document.querySelectorAll('img')].find(i => !i.closest('nav')"
                        f" && i.src === results[{path!r}].data_uri)")
            browser.wait_for(f"(() => {{ const i = {main_img}; return !!i && i.complete && i.naturalWidth > 0 }})()",
                             f"figure {path} displayed")
            size = browser.evaluate(f"(() => {{ const i = {main_img}; return [i.naturalWidth, i.naturalHeight] }})()")
            assert tuple(size) == _png_size(smoke_run / path), path
            assert browser.evaluate(NO_BROKEN_IMAGE), f"a broken image beside {path}"
        _show_figure(browser, shown[SCREENSHOT_FIGURE], SCREENSHOT_FIGURE)
        browser.wait_for(NO_BROKEN_IMAGE, "the screenshot's figure")
        shot = tmp_path / "report.png"
        browser.screenshot(shot)
        # The statistics view draws its charts with the embedded Vega.
        _click(browser, "document.querySelector('nav ol a')", "the home button")
        _click(browser, "[...document.querySelectorAll('nav a')].find(a => a.textContent.trim() === 'Statistics')",
               "menu entry Statistics")
        browser.wait_for("document.querySelectorAll('canvas, svg.marks').length > 0", "the statistics charts")
        external = [u for u in browser.requests if not u.startswith(LOCAL_SCHEMES)]
        assert not external, f"the report asked for {external}"
        assert not browser.failed, browser.failed
        assert not browser.exceptions, browser.exceptions
    assert _png_size(shot) == (1440, 900) and shot.stat().st_size > 50_000
    SCREENSHOT.parent.mkdir(exist_ok=True)
    shutil.copy(shot, SCREENSHOT)


def test_chromium_sees_outside_requests_and_broken_images(tmp_path):
    """The checks above are not blind: a page asking for a URL off the file (a closed port on this
    machine) and showing an undecodable image is caught by both."""
    _needs_chromium()
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    page = tmp_path / "page.html"
    page.write_text(f'<html><body><img id="a" src="http://127.0.0.1:{port}/figure.png">'
                    '<img id="b" src="data:image/png;base64,AAAA"></body></html>')
    with Chromium(tmp_path / "profile") as browser:
        browser.open(page.as_uri())
        assert f"http://127.0.0.1:{port}/figure.png" in browser.requests
        assert [u for u in browser.requests if not u.startswith(LOCAL_SCHEMES)]
        assert not browser.evaluate(NO_BROKEN_IMAGE)
