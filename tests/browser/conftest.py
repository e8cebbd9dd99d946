"""One chromium for every browser test (launching it costs a second or two each time); a module's
pages and contexts are closed when the module ends, so none of them polls a server that has gone."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from browser_helpers import chromium


@pytest.fixture(scope="session")
def browser() -> Iterator[object]:
    with chromium() as b:
        yield b


@pytest.fixture(scope="module", autouse=True)
def _close_the_modules_pages(browser) -> Iterator[None]:
    before = set(browser.contexts)
    yield
    for ctx in browser.contexts:
        if ctx not in before:
            ctx.close()
