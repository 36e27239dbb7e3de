"""Open an HTML report in Debian's headless Chromium, as a person would, and check it.

Driven with Playwright over the DevTools protocol (the ``playwright`` package of the dev
extra; it launches ``/usr/bin/chromium`` and downloads no browser). Chromium's own
``--dump-dom``/``--screenshot`` flags cannot report console messages, failed scripts or the
requests a page makes, which is what the check is about.
"""

from __future__ import annotations

import io
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

#: Flags of a quiet headless Chromium here: no sandbox (root), no background requests of its
#: own (updates, sync), which would otherwise show up as requests of the page's browser.
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def chromium() -> str:
    """Path of the Chromium binary; skips the test where there is none (fails under CI, whose
    .ci/run installs it)."""
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is not installed (.ci/run installs Debian's chromium)")
        pytest.skip("chromium not installed (apt-get install chromium)")
    return path


def not_blank(png: bytes) -> tuple[float, int]:
    """Fraction of pixels that are not near-white, and the number of distinct colours."""
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).reshape(-1, 3)
    ink = float(np.mean(img.min(axis=1) < 235))
    return ink, len(np.unique(img[:: max(1, len(img) // 20000)], axis=0))


def check_page(path: Path, shots: Path, click_row: tuple[str, str] | None = None) -> dict:
    """Load ``path`` from disk and assert: no console error or page error, no request but the
    file itself, every ``div.plot`` drawn (plotly's SVG inside) with a non-zero size and a
    non-blank picture. Writes ``shots/page.png`` (the whole page). ``click_row`` = (table
    name prefix, row key): click that row and return the selector's value as ``selected``.

    Returns
    -------
    dict
        ``plots`` (how many), ``selected``, ``console`` (every console message).
    """
    from playwright.sync_api import sync_playwright

    url = Path(path).resolve().as_uri()
    console, errors, requests = [], [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium(), args=FLAGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.on("console", lambda m: console.append((m.type, m.text)))
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("request", lambda r: requests.append(r.url))
            page.goto(url)
            page.wait_for_selector("body[data-ready=true]", state="attached", timeout=60_000)
            assert not errors, errors
            # plotly writes its warnings (a bad colour, say) with console.trace
            assert [m for m in console if m[0] in ("error", "warning", "trace")] == [], console
            assert requests == [url], requests
            plots = page.query_selector_all("div.plot")
            assert plots
            for div in plots:
                box = div.bounding_box()
                pid = div.get_attribute("id")
                assert box and box["width"] > 100 and box["height"] > 100, (pid, box)
                assert div.query_selector("svg.main-svg") is not None, pid
                ink, colours = not_blank(div.screenshot())
                assert ink > 0.01 and colours > 8, (pid, ink, colours)
            selected = None
            if click_row is not None:
                prefix, key = click_row
                row = page.query_selector(f'table.data[data-name^="{prefix}"] '
                                          f'tbody tr[data-choice="{key}"]')
                row.click()
                target = page.eval_on_selector(f'table.data[data-name^="{prefix}"]',
                                               "t => t.dataset.choice")
                selected = page.eval_on_selector(f'select[data-plot="{target}"]',
                                                 "s => s.value")
                title = page.eval_on_selector(f"#{target} .gtitle", "t => t.textContent")
                assert key in title, title
            shots.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(shots / "page.png"), full_page=True)
            assert not errors, errors
        finally:
            browser.close()
    return {"plots": len(plots), "selected": selected, "console": console}


def cells_out_of_view(path: Path, table: str, keys: list[str],
                      width: int = 1400) -> dict[str, dict]:
    """Open ``path`` in a ``width`` px wide window and scroll the table whose ``data-name``
    starts with ``table`` into view, vertically only (as a reader scrolls down to it). Returns
    the cells of ``keys`` (``td[data-k=KEY]`` of its first row) that are not wholly visible
    without a horizontal scroll: beyond the window's right edge or outside a scrolling
    container's visible part, with their boxes; empty when every one is in view."""
    from playwright.sync_api import sync_playwright

    script = """([table, keys]) => {
        const t = document.querySelector(`table.data[data-name^="${table}"]`);
        if (!t) return {missing: {table}};
        t.scrollIntoView({block: "start", inline: "nearest"});
        window.scrollTo(0, window.scrollY);
        let view = {left: 0, right: window.innerWidth};
        for (let e = t.parentElement; e; e = e.parentElement) {
            const s = getComputedStyle(e);
            if (["auto", "scroll", "hidden"].includes(s.overflowX)) {
                const r = e.getBoundingClientRect();
                view = {left: Math.max(view.left, r.left), right: Math.min(view.right, r.right)};
            }
        }
        const out = {};
        for (const k of keys) {
            const c = t.querySelector(`tbody tr td[data-k="${k}"]`);
            if (!c) { out[k] = {missing: true}; continue; }
            const r = c.getBoundingClientRect();
            if (r.left < view.left - 0.5 || r.right > view.right + 0.5)
                out[k] = {left: r.left, right: r.right, view};
        }
        return out;
    }"""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium(), args=FLAGS)
        try:
            page = browser.new_page(viewport={"width": width, "height": 900})
            page.goto(Path(path).resolve().as_uri())
            page.wait_for_selector("body[data-ready=true]", state="attached", timeout=60_000)
            return page.evaluate(script, [table, keys])
        finally:
            browser.close()
