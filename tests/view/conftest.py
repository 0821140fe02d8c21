"""Shared by the view tests: an analytic bake of the bumpy sphere (exact normals and colours baked onto a
decimated mesh), and the headless browser the page tests drive."""

import os

import pytest

from neural_bake.view.analytic import analytic_bake


@pytest.fixture(scope="session")
def bumpy_bake(tmp_path_factory):
    return analytic_bake(tmp_path_factory.mktemp("bumpy"))


@pytest.fixture(scope="session")
def make_analytic_bake():
    return analytic_bake


@pytest.fixture(scope="session")
def browser_ready():
    """Headless Chromium, Playwright and model-viewer for the tests that load a page: where one is missing the
    test is skipped with the reason, or fails under CI (the environment variable CI set), so that it never
    passes silently there."""
    from neural_bake.view.browser import browser_missing

    why = browser_missing()
    if why:
        if os.environ.get("CI"):
            pytest.fail(f"browser test cannot run under CI: {why}")
        pytest.skip(why)
