"""What the loader fuzz tests (``test_fuzz_*.py``) share: byte- and text-level mutations of a
valid file as hypothesis strategies, the per-case time guard, and the check that a case either
loads or raises the package's one-line error naming the file.

Every fuzz test runs through ``fuzz``: 200 cases from a fixed seed of its own, so CI sees the same
cases each run, no example database, and a per-case limit (hypothesis' deadline, and an alarm).
``HYPERBONES_FUZZ_CASES`` / ``HYPERBONES_FUZZ_SEED`` run more or other cases locally.
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import re
import signal
import time
import warnings
import zlib
from datetime import timedelta
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from hyperbones.errors import HyperbonesError

CASES = int(os.environ.get("HYPERBONES_FUZZ_CASES", 200))
"""Cases per loader; more (and ``HYPERBONES_FUZZ_SEED``, another fixed seed) for a deeper local run."""
CASE_SECONDS = 10.0
"""Hard limit of one case (``signal`` alarm); hypothesis' deadline is half of it."""

FUZZ_SETTINGS = settings(
    max_examples=CASES,
    derandomize=True,
    database=None,
    deadline=timedelta(seconds=CASE_SECONDS / 2),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example],
)

# What a number in a text file is replaced by, by kind (each kind equally likely).
SPECIAL_NUMBERS = {
    "non-finite": ("nan", "NaN", "inf", "-inf", "Infinity", "1e999", "-1e999"),
    "huge": ("1e308", "-1e308", "1e300", "3.5e38", "1e38", "1e20", "99999999999", "2147483648", "-2147483649"),
    "tiny": ("1e-320", "1e-300", "-1e-300", "1e-9"),
    "zero or negative": ("0", "-0", "0.0", "-1", "-7.5", "-100"),
    "not a number": ("1.5.2", "0x10", "1_0", "", "abc", "1e", "+-1", "١٢", "1,5"),
}
_NUMBER = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


class CaseTimeout(BaseException):
    """A case ran past its time limit (a BaseException, so no loader's ``except Exception`` hides it)."""


@contextlib.contextmanager
def time_limit(seconds: float = CASE_SECONDS):
    """Raise CaseTimeout in the main thread after ``seconds``; if the process is stuck in C code
    where the alarm cannot interrupt it, faulthandler dumps the stacks and exits after 3 × that."""

    def expire(signum, frame):
        raise CaseTimeout(f"the case ran longer than {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    faulthandler.dump_traceback_later(3 * seconds, exit=True)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        faulthandler.cancel_dump_traceback_later()
        signal.signal(signal.SIGALRM, previous)


def loads_or_fails_cleanly(load, path: str | Path | tuple | None = None, seconds: float = CASE_SECONDS):
    """Run ``load()`` under the time guard: its result, or None when it raised a HyperbonesError
    whose message is one non-empty line naming ``path`` (when given; one of them for a tuple). Any other exception
    propagates (the case fails); warnings must be one line too."""
    with time_limit(seconds), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = load()
        except HyperbonesError as error:
            check_message(str(error), path)
            result = None
    for warning in caught:
        text = str(warning.message)
        assert "\n" not in text and "\r" not in text, f"multi-line warning: {text!r}"
    return result


def check_message(message: str, path: str | Path | tuple | None = None) -> None:
    """A one-line error message that names ``path`` (when given; one of them for a tuple) and
    says something more."""
    assert message.strip(), "empty error message"
    assert "\n" not in message and "\r" not in message, f"multi-line message: {message!r}"
    if path is not None:
        named = [str(p) for p in (path if isinstance(path, tuple) else (path,)) if str(p) in message]
        assert named, f"message does not name the file {path}: {message!r}"
        assert message.replace(named[0], "").strip(" :"), f"message names the file but no problem: {message!r}"


def fuzz(strategy: st.SearchStrategy, case) -> None:
    """Run ``case(value)`` on ``CASES`` values of ``strategy`` with ``FUZZ_SETTINGS``. Called inside a
    plain test, so that a failure reports the drawn value alone, not the test's (large) fixtures;
    each test has its own fixed seed (``run`` looks the same in all, so derandomize alone would not)."""

    @FUZZ_SETTINGS
    @seed(zlib.crc32(case.__qualname__.encode()) + int(os.environ.get("HYPERBONES_FUZZ_SEED", 0)))
    @given(strategy)
    def run(value):
        case(value)

    run()


def write_case(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def special_numbers() -> st.SearchStrategy[str]:
    return st.sampled_from(list(SPECIAL_NUMBERS)).flatmap(lambda kind: st.sampled_from(SPECIAL_NUMBERS[kind]))


# --- byte-level mutations ---------------------------------------------------------------------

@st.composite
def _byte_mutation(draw, data: bytes) -> bytes:
    n = len(data)
    kind = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "overwrite", "zero"]))
    at = draw(st.integers(0, max(n - 1, 0)))
    if kind == "truncate":
        return data[:at]
    if kind == "flip":
        if not n:
            return data
        return data[:at] + bytes([data[at] ^ draw(st.integers(1, 255))]) + data[at + 1:]
    if kind == "insert":
        return data[:at] + draw(st.binary(min_size=1, max_size=16)) + data[at:]
    if kind == "delete":
        return data[:at] + data[at + draw(st.integers(1, 64)):]
    if kind == "overwrite":
        patch = draw(st.binary(min_size=1, max_size=16))
        return data[:at] + patch + data[at + len(patch):]
    return data[:at] + bytes(draw(st.integers(1, 64))) + data[at + 64:]


# --- text-level mutations (on bytes, so they also make invalid UTF-8 when combined) ---------------

@st.composite
def _text_mutation(draw, data: bytes) -> bytes:
    lines = data.splitlines(keepends=True)
    kind = draw(st.sampled_from(["number"] * 4 + ["every-number", "drop", "duplicate", "swap", "shuffle", "blank",
                                                  "truncate-line", "token"]))
    if kind in ("number", "every-number"):
        spans = [m.span() for m in _NUMBER.finditer(data)]
        if not spans:
            return data
        # Half the time among the first tenth: headers are few numbers before much data.
        last = len(spans) - 1 if draw(st.booleans()) else len(spans) // 10
        start, end = spans[draw(st.integers(0, last))]
        special = draw(special_numbers()).encode()
        if kind == "every-number":  # each occurrence of that number (as a whole word)
            return re.sub(rb"(?<![\w.+-])" + re.escape(data[start:end]) + rb"(?![\w.])", special, data)
        return data[:start] + special + data[end:]
    if not lines:
        return data
    i = draw(st.integers(0, len(lines) - 1))
    if kind == "drop":
        return b"".join(lines[:i] + lines[i + 1:])
    if kind == "duplicate":
        return b"".join(lines[:i + 1] + lines[i:])
    if kind == "swap":
        j = draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
        return b"".join(lines)
    if kind == "shuffle":  # a block of lines moved elsewhere (sections out of order)
        j = draw(st.integers(i, min(len(lines), i + 40)))
        block, rest = lines[i:j], lines[:i] + lines[j:]
        k = draw(st.integers(0, len(rest)))
        return b"".join(rest[:k] + block + rest[k:])
    if kind == "blank":
        return b"".join(lines[:i] + [b"\n"] + lines[i:])
    if kind == "truncate-line":
        cut = draw(st.integers(0, len(lines[i])))
        return b"".join(lines[:i] + [lines[i][:cut]] + lines[i + 1:])
    # one word of a line replaced by another word of the file or by garbage
    words = lines[i].split()
    if not words:
        return data
    w = draw(st.integers(0, len(words) - 1))
    other = draw(st.sampled_from([b"", b"{", b"}", b"x", b"-", b"\xff\xfe", b"\t", b"#", b"=", b"[", b"]", b'"',
                                  *data.split()[:200]]))
    words[w] = other
    return b"".join(lines[:i] + [b" ".join(words) + b"\n"] + lines[i + 1:])


@st.composite
def number_in_lines(draw, data: bytes, pattern: bytes) -> bytes:
    """A number on one of the lines matching ``pattern`` (a regex) replaced by a special one: aims
    the mutations at a format's sensitive lines (a BVH's OFFSETs, an OBJ's vertices)."""
    lines = data.split(b"\n")
    candidates = [i for i, line in enumerate(lines) if re.match(pattern, line)]
    if not candidates:
        return data
    i = candidates[draw(st.integers(0, len(candidates) - 1))]
    spans = [m.span() for m in _NUMBER.finditer(lines[i])]
    if not spans:
        return data
    start, end = spans[draw(st.integers(0, len(spans) - 1))]
    lines[i] = lines[i][:start] + draw(special_numbers()).encode() + lines[i][end:]
    return b"\n".join(lines)


def mutations(data: bytes, text: bool = True, max_steps: int = 3, min_steps: int = 1) -> st.SearchStrategy[bytes]:
    """``data`` changed by ``min_steps`` (1) to ``max_steps`` mutations: text-level ones (numbers to NaN, inf, huge
    or negative values; lines dropped, duplicated, swapped, moved, cut) when ``text``, and
    byte-level ones (truncation, flipped, inserted, deleted or zeroed bytes)."""
    step = (lambda d: st.one_of(_text_mutation(d), _text_mutation(d), _byte_mutation(d))) if text \
        else _byte_mutation

    @st.composite
    def chain(draw):
        out = data
        for _ in range(draw(st.integers(min_steps, max_steps))):
            out = draw(step(out))
        return out

    return chain()


# --- the support itself ---------------------------------------------------------------------

def test_time_limit_stops_a_hanging_loader():
    start = time.perf_counter()
    with pytest.raises(CaseTimeout):
        loads_or_fails_cleanly(lambda: time.sleep(30), seconds=0.2)
    assert time.perf_counter() - start < 5


def test_check_message_wants_one_line_naming_the_file():
    check_message("/tmp/x.bvh: line 3: bad", "/tmp/x.bvh")
    for bad, path in (("/tmp/x.bvh: a\nb", "/tmp/x.bvh"), ("line 3: bad", "/tmp/x.bvh"), ("/tmp/x.bvh: ", "/tmp/x.bvh"),
                      ("", None)):
        with pytest.raises(AssertionError):
            check_message(bad, path)

