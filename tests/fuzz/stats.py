"""Counts of outcomes per file kind over a session, and the table the session prints."""

from __future__ import annotations

from collections import Counter, defaultdict

from tests.fuzz.runner import OUTCOMES

STATS: dict[str, Counter] = defaultdict(Counter)
"""kind -> outcome -> count (``tried``: inputs run)."""
FAILURES: list[tuple[str, dict, str]] = []
"""(kind, case, summary) of every run that broke the contract."""


def record(kind: str, case: dict, result) -> None:
    STATS[kind]["tried"] += 1
    STATS[kind][result.outcome] += 1
    if result.outcome not in ("ok", "flagged", "clear"):
        FAILURES.append((kind, case, result.summary()))


def table() -> str:
    """The counts as a markdown table, one row per kind and a total."""
    from tests.fuzz.cases import KINDS

    cols = ("tried", *OUTCOMES)
    head = "| kind | " + " | ".join(cols) + " |"
    lines = [head, "|---" * (len(cols) + 1) + "|"]
    total: Counter = Counter()
    for kind in sorted(STATS, key=lambda k: (KINDS.index(k) if k in KINDS else 99, k)):
        c = STATS[kind]
        total.update(c)
        lines.append(f"| {kind} | " + " | ".join(str(c[k]) for k in cols) + " |")
    lines.append("| **all** | " + " | ".join(str(total[k]) for k in cols) + " |")
    return "\n".join(lines)
