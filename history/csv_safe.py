"""CSV cells that a spreadsheet will not run: OWASP's rule against CSV (formula) injection.

A cell that begins with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return is read by Excel,
LibreOffice and Google Sheets as a formula; such a text cell gets a leading single quote, which the
spreadsheet shows as text. Numbers are written as numbers (a negative coordinate stays ``-1.5``),
so only text that a person or a client typed (names, notes, sources, error messages) changes.
Every CSV the project writes goes through :func:`writer`.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from typing import IO, Any

FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def cell(value: Any) -> Any:
    """``value`` as it is safe to write: text starting like a formula gets a leading ``'``."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


class SafeWriter:
    """:func:`csv.writer` whose rows go through :func:`cell`."""

    def __init__(self, fh: IO[str], **kwargs: Any) -> None:
        self._w = csv.writer(fh, **kwargs)

    def writerow(self, row: Iterable[Any]) -> Any:
        return self._w.writerow([cell(v) for v in row])

    def writerows(self, rows: Iterable[Iterable[Any]]) -> None:
        for row in rows:
            self.writerow(row)


def writer(fh: IO[str], **kwargs: Any) -> SafeWriter:
    """A CSV writer for ``fh`` (keyword arguments as :func:`csv.writer`'s) that neutralises formula cells."""
    return SafeWriter(fh, **kwargs)
