"""How hard the property tests try: ``GUADAL_FUZZ_EXAMPLES`` scales every one of them.

CI runs the defaults (a few hundred cases in all, well under a minute); a long run sets, say,
``GUADAL_FUZZ_EXAMPLES=20`` to try twenty times as many. Hypothesis keeps its example database in
``.hypothesis/`` (not in git).
"""

from __future__ import annotations

import os


def examples(default: int) -> int:
    """``default`` examples, times the factor in ``GUADAL_FUZZ_EXAMPLES`` (1 when unset)."""
    factor = float(os.environ.get("GUADAL_FUZZ_EXAMPLES", "1") or 1)
    return max(1, round(default * factor))
