"""Print the fuzz harness's counts per file kind: runs tests/test_fuzz.py (the quick,
derandomized cases; ``--thorough`` the slow ones too; ``--corpus`` replays the corpus and
lists the cases that fail, by the branch that owns their reader) and prints the table.

    python -m tests.fuzz.report [--thorough] [--corpus] [pytest options]
"""

from __future__ import annotations

import sys
from collections import defaultdict

import pytest


def main(argv: list[str]) -> int:
    args = ["-q", "-p", "no:cacheprovider", "-p", "no:logging", "--tb=no"]
    tests = ["tests/test_fuzz.py::test_fuzz"]
    if "--thorough" in argv:
        tests.append("tests/test_fuzz.py::test_fuzz_thorough")
        args += ["-m", "slow or not slow"]
    if "--corpus" in argv:
        tests = ["tests/test_fuzz.py::test_corpus"] + tests * ("--thorough" in argv)
    argv = [a for a in argv if a not in ("--thorough", "--corpus")]
    code = pytest.main(tests + args + argv)
    from tests.fuzz.stats import FAILURES  # the table: printed by tests/conftest.py's hook
    owners: dict[str, list[str]] = defaultdict(list)
    for kind, case, summary in FAILURES:
        if kind == "corpus":
            said = " | ".join(line.strip() for line in summary.splitlines()[-2:])
            owners[case.get("owner", "?")].append(f"{case['file']}: {said[-200:]}")
    for owner in sorted(owners):
        print(f"\ncorpus cases failing, {owner} ({len(owners[owner])}):")
        print("\n".join(f"  {line}" for line in sorted(owners[owner])))
    return int(code)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
