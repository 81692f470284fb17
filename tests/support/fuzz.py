"""How hard the property tests try: ``GUADAL_FUZZ_EXAMPLES`` scales every one of them.

CI runs the defaults (a few hundred cases in all, well under a minute); a long run sets, say,
``GUADAL_FUZZ_EXAMPLES=20`` to try twenty times as many. Hypothesis keeps its example database in
``.hypothesis/`` (not in git).
"""

from __future__ import annotations

import contextlib
import copy
import os
import signal

from hypothesis import strategies as st


def examples(default: int) -> int:
    """``default`` examples, times the factor in ``GUADAL_FUZZ_EXAMPLES`` (1 when unset)."""
    factor = float(os.environ.get("GUADAL_FUZZ_EXAMPLES", "1") or 1)
    return max(1, round(default * factor))


# --- mutations --------------------------------------------------------------------------
#: values a careless or hostile user puts in a field
NASTY = st.one_of(
    st.sampled_from(
        [
            None,
            True,
            False,
            0,
            -1,
            1,
            2**63,
            -(2**63),
            10**30,
            float("nan"),
            float("inf"),
            -float("inf"),
            1e308,
            -1e308,
            1e-300,
            5e-324,
            0.5,
            "",
            "x" * 5000,
            "a\x00b",
            "/",
            "/dev/null/x",
            "/proc/x",
            "../..",
            [],
            {},
            [[[]]],
            {"type": "x"},
            {"type": "gp"},
            "auto",
            "nan",
            "1e400",
        ]
    ),
    st.integers(),
    st.floats(),
    st.text(max_size=20),
    st.lists(st.integers(-3, 400), max_size=4),
).map(copy.deepcopy)  # a fresh copy: a mutation must never change the constants above


def paths_of(data, prefix=()) -> list[tuple]:
    """Every key path of a nested dict/list, the root (``()``) included."""
    out = [prefix]
    if isinstance(data, dict):
        for key, value in data.items():
            out.extend(paths_of(value, prefix + (key,)))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            out.extend(paths_of(value, prefix + (i,)))
    return out


def set_at(data, path: tuple, value, delete: bool = False):
    """``data`` with the value at ``path`` replaced (or deleted); a missing dict is made."""
    if not path:
        return value
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    if not isinstance(parent, (dict, list)):
        return data
    last = path[-1]
    if delete:
        del parent[last]
    elif isinstance(parent, list) and not isinstance(last, int):
        parent.append(value)
    else:
        parent[last] = value
    return data


def assert_one_sentence(exc: Exception) -> None:
    """What the user reads: one line that says something, no traceback."""
    text = str(exc)
    assert text.strip(), "an empty error message"
    assert "\n" not in text.strip(), f"more than one line: {text!r}"
    assert "Traceback" not in text


class Hang(Exception):
    """A case ran past its time limit."""


@contextlib.contextmanager
def time_limit(seconds: float):
    """Fail a case that runs longer than ``seconds`` (a hang), not how fast it runs."""

    def _expired(signum, frame):
        raise Hang(f"still running after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, _expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
