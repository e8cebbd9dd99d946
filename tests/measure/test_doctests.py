"""The docstring examples of measure's public API run as doctests."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ["measure.types", "measure.distance", "measure.sequence", "measure.dline", "measure.censored", "measure.confidence", "measure.shape"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.attempted > 0, f"{name} has no docstring examples"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (output above)"
