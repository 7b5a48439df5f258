"""Headless Debian chromium through Playwright, for the browser tests (tests/services/api/ui, tests/core/viewer).

Playwright cannot download its own browsers here, so it drives `/usr/bin/chromium` (apt package
`chromium`; `.ci/browser.sh` installs it). The flags keep a closed network from stalling start-up
on background connections. Without the binary the tests skip with a message saying so.
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = Path(os.environ.get("BFIELDS_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
]  # fmt: skip


def require_chromium() -> None:
    if not CHROMIUM.is_file():
        pytest.skip(f"browser tests need {CHROMIUM} (apt-get install chromium; .ci/browser.sh does it)")
    pytest.importorskip("playwright.sync_api", reason="browser tests need playwright (the dev extra)")


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """One chromium per test module, registered for every directory by the root conftest (a
    Playwright sync context is tied to the thread that opened it; a module's browser closes
    before the next module's opens)."""
    require_chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        yield b
        b.close()


def pixels(png: bytes) -> np.ndarray:
    """(H, W, 3) uint8 of a PNG screenshot."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
