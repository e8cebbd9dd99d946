"""What every fuzz test asserts: a typed error with a message, or an answer; never another
exception or a warning. Strategies shared by several surfaces."""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from hypothesis import strategies as st

T = TypeVar("T")

# Odd text: control characters, surrogate-free unicode, NUL, separators of the formats under test.
ODD_TEXT = st.text(
    alphabet=st.one_of(
        st.characters(codec="utf-8", exclude_categories=("Cs",)),
        st.sampled_from(list("\x00\n\r\t ?&=:#%[]{}\"'\\/.,;") + ["é", "\u202e", "\ufeff", "😀", "~"]),
    ),
    max_size=40,
)
# Numbers at and beyond the edges of every range.
EDGE_FLOATS = st.one_of(
    st.sampled_from([0.0, -0.0, 1e-300, 1e-30, 1e-9, 0.5, 1.0, 3.0, 1e6, 1e30, 1e300, -1.0, -1e30, math.inf, -math.inf, math.nan]),
    st.floats(allow_nan=True, allow_infinity=True),
)


@contextlib.contextmanager
def no_warnings() -> Iterator[None]:
    """Any warning inside is an error (not only those of our modules, which pytest's config catches)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def typed_or_answer(call: Callable[[], T], errors: type[BaseException] | tuple[type[BaseException], ...]) -> T | None:
    """``call()``'s answer, or None when it raised one of ``errors`` with a non-empty message.

    Any other exception, and any warning, propagates and fails the test."""
    with no_warnings():
        try:
            return call()
        except errors as exc:
            assert str(exc).strip(), f"{type(exc).__name__} without a message"
            return None


def allowing(category: type[Warning], call: Callable[[], T], names: tuple[str, ...]) -> Callable[[], T]:
    """``call`` letting through warnings of ``category`` (a reader's own, documented warning) that name
    one of ``names``; any other warning is still an error, as in :func:`typed_or_answer`."""

    def run() -> T:
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("error")
            warnings.simplefilter("always", category)
            answer = call()
        for w in seen:
            assert any(n in str(w.message) for n in names), f"the warning names none of {names}: {w.message}"
        return answer

    return run


def finite(value: Any) -> bool:
    try:
        return all(math.isfinite(float(v)) for v in (value if isinstance(value, (tuple, list)) else [value]))
    except (TypeError, ValueError):
        return False


RECORDING_TOKENS = (b"\xff", b"\x00", b"\n", b"{", b"}", b'"', b"9" * 20, b"NaN", b"-", b"\xc3")


@st.composite
def byte_edits(draw: st.DrawFn, data: bytes, tokens: tuple[bytes, ...] = RECORDING_TOKENS, *, edits: int = 5,
               cut: int = 16, repeat: bool = False) -> bytes:
    """``data`` with 1..``edits`` edits: a byte replaced, up to ``cut`` bytes deleted, a token inserted, and
    the tail cut off (or, with ``repeat``, a stretch of up to 200 bytes repeated up to 4 times)."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, edits))):
        i = draw(st.integers(0, max(0, len(out) - 1)))
        op = draw(st.integers(0, 3))
        if op == 0 and out:
            out[i] = draw(st.integers(0, 255))
        elif op == 1:
            del out[i : i + draw(st.integers(1, cut))]
        elif op == 2:
            out[i:i] = draw(st.sampled_from(tokens))
        elif repeat:
            out[i:i] = out[i : i + draw(st.integers(1, 200))] * draw(st.integers(1, 4))
        else:
            del out[i:]
    return bytes(out)
