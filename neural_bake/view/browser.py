"""Drive a report in headless Chromium (Debian's package) with Playwright: load, wait for model-viewer, screenshot.

Playwright cannot download its own browsers here; it drives the system's ``chromium`` through
``executable_path``. SwiftShader gives WebGL2 on the CPU (``--use-angle=swiftshader``).
"""

from __future__ import annotations

import contextlib
import shutil
import time
from pathlib import Path
from typing import Iterator

from .meshes import ViewError

__all__ = ["CHROMIUM_ARGS", "find_chromium", "browser_missing", "screenshot_viewer", "drag_linked_viewers",
           "screenshot_page"]

#: Launch flags: headless, no sandbox (root in containers), WebGL on the CPU, no background traffic.
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


def find_chromium() -> str | None:
    """Path of a Chromium executable (PATH, then /usr/bin/chromium), or None."""
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return "/usr/bin/chromium" if Path("/usr/bin/chromium").is_file() else None


def browser_missing() -> str:
    """Why a report cannot be checked in a browser here ("" when Chromium, Playwright and model-viewer are all there)."""
    from .viewer import find_model_viewer

    missing = []
    if find_chromium() is None:
        missing.append("no chromium executable (Debian: apt-get install chromium)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing.append("the Python package playwright is not installed (pip install -e '.[test]')")
    if find_model_viewer()[0] is None:
        missing.append(find_model_viewer()[1])
    return "; ".join(missing)


@contextlib.contextmanager
def _page(index: Path, width: int, height: int, logs: list[tuple[str, str]] | None = None) -> Iterator:
    """A headless Chromium page of ``width`` × ``height`` showing ``index`` (file://), its console messages and
    page errors appended to ``logs``; the browser is closed on leaving. :class:`ViewError` when it cannot run."""
    why = browser_missing()
    if why:
        raise ViewError(f"browser check: {why}")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium(), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            if logs is not None:
                page.on("console", lambda m: logs.append((m.type, m.text[:300])))
                page.on("pageerror", lambda e: logs.append(("pageerror", str(e)[:300])))
            page.goto(index.as_uri())
            yield page
        finally:
            browser.close()


def screenshot_viewer(index, out, *, show: str = "baked", timeout_s: float = 180.0, settle_ms: int = 1500) -> dict:
    """Open report ``index`` (file://) in headless Chromium, wait for model-viewer's ``load`` event and for the
    model to be visible, let ``settle_ms`` pass, and screenshot the viewer element into PNG ``out``.

    Returns ``{"console": [(type, text)], "seconds_to_load": s, "seconds_total": s}``; page errors are in
    ``console`` with type "pageerror". Raises :class:`ViewError` when the browser cannot run or model-viewer
    reports an error.
    """
    index = Path(index).resolve()
    logs: list[tuple[str, str]] = []
    t0 = time.perf_counter()
    with _page(index, 1000, 900, logs) as page:
        wait = int(timeout_s * 1000)
        page.wait_for_function("window.NEURAL_BAKE_LOADED >= 1 || window.NEURAL_BAKE_ERROR", timeout=wait)
        error = page.evaluate("window.NEURAL_BAKE_ERROR || null")
        if error:
            raise ViewError(f"{index}: model-viewer failed to load the model ({error})")
        if show != "baked":
            page.evaluate(f"window.NEURAL_BAKE_LOADED = 0; show({show!r})")
            page.wait_for_function("window.NEURAL_BAKE_LOADED >= 1", timeout=wait)
        page.wait_for_function("window.NEURAL_BAKE_VISIBLE === true", timeout=wait)
        loaded = time.perf_counter() - t0
        page.wait_for_timeout(settle_ms)  # the environment's prefiltering and a few frames
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        page.screenshot(path=str(out), clip=_clip(page, "#viewer"))
    return {"console": logs, "seconds_to_load": loaded, "seconds_total": time.perf_counter() - t0}


def _clip(page, selector: str) -> dict:
    box = page.locator(selector).bounding_box()
    return {"x": round(box["x"]), "y": round(box["y"]), "width": round(box["width"]), "height": round(box["height"])}


def drag_linked_viewers(index, out_dir, *, drag: tuple[float, float] = (120.0, 0.0), timeout_s: float = 180.0,
                        settle_ms: int = 1500, page_shot=None) -> dict:
    """Open a comparison page (file://) in headless Chromium, wait until every linked viewer loaded its GLB,
    screenshot each (``before_I.png`` in ``out_dir``), drag the mouse across the first by ``drag`` pixels,
    and screenshot each again (``after_I.png``). ``page_shot``: also save a screenshot of the whole page's
    first screen there (PNG path).

    Returns ``{"viewers": n, "orbits_before": [[θ, φ, r] per viewer], "orbits_after": […], "console": […]}``
    (radians and metres, as model-viewer reports them). Raises :class:`ViewError` when the browser cannot run
    or a viewer reports an error.
    """
    index, out_dir = Path(index).resolve(), Path(out_dir)
    logs: list[tuple[str, str]] = []
    orbit_js = "[...document.querySelectorAll('model-viewer.linked')].map(m=>{const o=m.getCameraOrbit();" \
               "return [o.theta,o.phi,o.radius];})"
    with _page(index, 1200, 900, logs) as page:
        wait = int(timeout_s * 1000)
        n = page.evaluate("document.querySelectorAll('model-viewer.linked').length")
        if not n:
            raise ViewError(f"{index}: no linked viewers on the page")
        page.wait_for_function(f"window.NEURAL_BAKE_LOADED >= {n} || window.NEURAL_BAKE_ERROR", timeout=wait)
        error = page.evaluate("window.NEURAL_BAKE_ERROR || null")
        if error:
            raise ViewError(f"{index}: model-viewer failed to load a model ({error})")
        page.wait_for_timeout(settle_ms)
        if page_shot is not None:
            page.screenshot(path=str(page_shot))
        before = page.evaluate(orbit_js)
        for i in range(n):
            page.screenshot(path=str(out_dir / f"before_{i}.png"), clip=_clip(page, f"#viewer{i}"))
        box = page.locator("#viewer0").bounding_box()
        x0, y0 = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(x0, y0)
        page.mouse.down()
        for k in range(1, 11):
            page.mouse.move(x0 + drag[0] * k / 10, y0 + drag[1] * k / 10)
            page.wait_for_timeout(30)
        page.mouse.up()
        page.wait_for_timeout(settle_ms)
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        after = page.evaluate(orbit_js)
        for i in range(n):
            page.screenshot(path=str(out_dir / f"after_{i}.png"), clip=_clip(page, f"#viewer{i}"))
    return {"viewers": n, "orbits_before": before, "orbits_after": after, "console": logs}


def screenshot_page(index, out, *, width: int = 1200, height: int = 900, timeout_s: float = 180.0,
                    settle_ms: int = 2500) -> Path:
    """Open a report or comparison page (file://) in headless Chromium, wait until its viewers loaded their
    GLBs (``window.NEURAL_BAKE_LOADED``, when the page has viewers), and save the first ``width`` × ``height``
    pixels of the page as PNG ``out``; return ``out``."""
    with _page(Path(index).resolve(), width, height) as page:
        n = page.evaluate("document.querySelectorAll('model-viewer').length")
        if n:
            page.wait_for_function(f"window.NEURAL_BAKE_LOADED >= {n} || window.NEURAL_BAKE_ERROR",
                                   timeout=int(timeout_s * 1000))
        page.wait_for_timeout(settle_ms)
        page.screenshot(path=str(out))
    return Path(out)
