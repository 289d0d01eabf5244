"""Print the fuzz harness's counts per file kind: runs tests/test_fuzz.py (the quick,
derandomized cases; ``--thorough`` for the slow ones too) and prints the table.

    python -m tests.fuzz.report [--thorough] [pytest options]
"""

from __future__ import annotations

import sys

import pytest


def main(argv: list[str]) -> int:
    args = ["tests/test_fuzz.py::test_fuzz", "-q", "-p", "no:cacheprovider"]
    if "--thorough" in argv:
        argv = [a for a in argv if a != "--thorough"]
        args += ["tests/test_fuzz.py::test_fuzz_thorough", "-m", "slow or not slow"]
    code = pytest.main(args + argv)
    from tests.fuzz.stats import table

    print(table())
    return int(code)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
