"""``hyperbones view`` in headless Chromium (Playwright driving Debian's browser): the page shows the body and the garment, and a
body-shape slider moved through viser's API makes a new scene whose garment is drawn anew."""

from __future__ import annotations

import os
import shutil
import socket
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hyperbones.cli import main

SCENE = (slice(150, 780), slice(300, 780))  # rows, columns of a 1200×800 page left of viser's panel


def _chromium() -> str:
    """Debian's chromium (.ci/run installs it); skipped where absent outside CI."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing: .ci/run installs Debian's chromium package")
        pytest.skip("headless Chromium (Debian's chromium package) is needed")
    return found


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def page():
    """A headless Chromium page (Debian's browser, driven by Playwright), 1200×800."""
    from playwright.sync_api import sync_playwright

    chromium = _chromium()
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, headless=True, args=[
            "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync"])
        yield browser.new_page(viewport={"width": 1200, "height": 800})
        browser.close()


def _screenshot(page, url: str, status: str, path: Path) -> np.ndarray:
    """(H,W,3) int pixels of ``url`` once the viewer's panel says ``status`` and the meshes
    have been drawn (software WebGL)."""
    page.goto(url)
    page.get_by_text(status).wait_for(timeout=120_000)
    page.wait_for_timeout(3000)  # the scene's messages drawn
    page.screenshot(path=str(path))
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def _garment_pixels(image: np.ndarray) -> np.ndarray:
    """Where the page is the garment's blue (lit or washed out by the lights)."""
    red, green, blue = np.moveaxis(image[SCENE], -1, 0)
    return (blue > red + 50) & (blue > 110)


def _body_pixels(image: np.ndarray) -> np.ndarray:
    """Where the page is skin: warm, where the floor, grid and shadows are grey."""
    red, green, blue = np.moveaxis(image[SCENE], -1, 0)
    return (red > blue + 8) & (red >= green)


def test_viewer_page_shows_body_and_garment_and_a_slider_remakes_the_garment(page, tmp_path):
    from hyperbones.viewer.app import Viewer
    from hyperbones.viewer.choice import Choice

    viewer = Viewer(Choice(garment="tshirt", method="lbs", vertices=1000, frames=20), ["tshirt", "dress"],
                    ["walk"], port=_free_port(), playing=False)
    try:
        assert viewer.wait_ready(600), viewer.status.content
        url = f"http://127.0.0.1:{viewer.port}/"
        first = _screenshot(page, url, "tshirt on body default", tmp_path / "first.png")
        garment, body = _garment_pixels(first), _body_pixels(first)
        assert garment.sum() > 2000, "no garment on the page"
        assert body.sum() > 2000, "no body on the page"
        before = viewer.garment_frames.copy()

        viewer.body["height"].value = 1.0  # as a user's drag does: viser calls the slider's callbacks
        assert viewer.wait_ready(600), viewer.status.content
        after = viewer.garment_frames
        assert viewer.shown.body.height == pytest.approx(1.0)
        # The t-shirt remade on a taller body (the template is fitted anew): its collar higher up.
        top = [frames[0, :, 2].max() for frames in (before, after)]
        assert top[1] > top[0] + 0.05, top
        np.testing.assert_array_equal(viewer._meshes["garment"].vertices, after[0])  # what the page is sent

        second = _screenshot(page, url, "tshirt on body height=1", tmp_path / "second.png")
        rows = [np.flatnonzero(mask.any(axis=1))[0] for mask in (garment, _garment_pixels(second))]
        assert rows[1] < rows[0] - 10, f"the garment's top on the page moved from row {rows[0]} to {rows[1]}"
    finally:
        viewer.close()


def test_view_refuses_a_missing_file_in_one_line(capsys):
    assert main(["view", "--garment", "no-such-shirt.obj"]) == 2
    error = capsys.readouterr().err.strip()
    assert error == "hyperbones: error: no-such-shirt.obj: file not found (a garment template, a built-in " \
                    "motion or a file was expected)"
    assert main(["view", "--method", "teacher"]) == 2
    assert "view --method must be one of hyperbones, lbs" in capsys.readouterr().err
