"""Drive a report in headless Chromium (Debian's package) with Playwright: load, wait for model-viewer, screenshot.

Playwright cannot download its own browsers here; it drives the system's ``chromium`` through
``executable_path``. SwiftShader gives WebGL2 on the CPU (``--use-angle=swiftshader``).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from .meshes import ViewError

__all__ = ["CHROMIUM_ARGS", "find_chromium", "browser_missing", "screenshot_viewer"]

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


def screenshot_viewer(index, out, *, show: str = "baked", timeout_s: float = 180.0, settle_ms: int = 1500) -> dict:
    """Open report ``index`` (file://) in headless Chromium, wait for model-viewer's ``load`` event and for the
    model to be visible, let ``settle_ms`` pass, and screenshot the viewer element into PNG ``out``.

    Returns ``{"console": [(type, text)], "seconds_to_load": s, "seconds_total": s}``; page errors are in
    ``console`` with type "pageerror". Raises :class:`ViewError` when the browser cannot run or model-viewer
    reports an error.
    """
    why = browser_missing()
    if why:
        raise ViewError(f"browser check: {why}")
    from playwright.sync_api import sync_playwright

    index = Path(index).resolve()
    logs: list[tuple[str, str]] = []
    t0 = time.perf_counter()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium(), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1000, "height": 900})
            page.on("console", lambda m: logs.append((m.type, m.text[:300])))
            page.on("pageerror", lambda e: logs.append(("pageerror", str(e)[:300])))
            page.goto(index.as_uri())
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
            box = page.locator("#viewer").bounding_box()
            page.screenshot(path=str(out), clip={"x": round(box["x"]), "y": round(box["y"]),
                                                 "width": round(box["width"]), "height": round(box["height"])})
        finally:
            browser.close()
    return {"console": logs, "seconds_to_load": loaded, "seconds_total": time.perf_counter() - t0}
