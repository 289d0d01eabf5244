"""The training entry point parses and knows its defaults (decoders arrive with the tasks)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_train_py_help_lists_fit():
    out = subprocess.run([sys.executable, str(ROOT / "train.py"), "--help"], capture_output=True,
                         text=True, check=True, cwd=ROOT).stdout
    assert "fit" in out and "validate" in out


def test_a_bad_thread_cap_is_one_line():
    done = subprocess.run([sys.executable, str(ROOT / "train.py"), "fit", "--help"],
                          capture_output=True, text=True, cwd=ROOT,
                          env=os.environ | {"WTML_THREADS": "abc"})
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "train.py: error: $WTML_THREADS: must be a positive integer, got 'abc'"]


def test_training_computes_on_the_cores_it_may_use(monkeypatch):
    """Under a container's CPU quota (``available_cores`` below torch's own default of the
    machine's cores) training's torch threads are capped to it."""
    import torch

    from wtml import training

    before = torch.get_num_threads()
    monkeypatch.setattr(training, "available_cores", lambda: 1)
    try:
        with pytest.raises(SystemExit) as done:
            training.cli_main(["fit", "--help"])
        assert done.value.code == 0 and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
