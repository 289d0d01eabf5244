"""The training entry point parses and knows its defaults (decoders arrive with the tasks)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_train_py_help_lists_fit():
    out = subprocess.run([sys.executable, str(ROOT / "train.py"), "--help"], capture_output=True,
                         text=True, check=True, cwd=ROOT).stdout
    assert "fit" in out and "validate" in out
