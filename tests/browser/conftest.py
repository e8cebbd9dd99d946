"""One chromium for the browser tests (launching it costs a second or two each time), started by the
first one and stopped after the last one: Playwright's sync API runs an event loop in the main thread,
which the tests after these (``asyncio.run``) must not find. A module's contexts are closed when it
ends, so none of its pages polls a server that has gone."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from browser_helpers import launch

HERE = Path(__file__).resolve().parent
_running: dict[str, object] = {}


def _shared_browser():
    if "browser" not in _running:
        from playwright.sync_api import sync_playwright

        pw = sync_playwright().start()
        _running["playwright"] = pw
        _running["browser"] = launch(pw)
    return _running["browser"]


def _stop() -> None:
    browser, pw = _running.pop("browser", None), _running.pop("playwright", None)
    if browser is not None:
        browser.close()
    if pw is not None:
        pw.stop()


@pytest.fixture(scope="module")
def browser():
    return _shared_browser()


@pytest.fixture(scope="module", autouse=True)
def _close_the_modules_pages() -> Iterator[None]:
    yield
    if "browser" in _running:
        for ctx in _running["browser"].contexts:
            ctx.close()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    try:
        return (yield)
    finally:
        if nextitem is None or HERE not in nextitem.path.parents:  # the last browser test for now
            _stop()
