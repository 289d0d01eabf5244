"""A pool's workers end with the process that owns the pool (:mod:`wtml.workers`)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from wtml.workers import watch_parent

OWNER = """
import sys, time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from wtml.workers import watch_parent
watched = sys.argv[1] == "watched"
pool = ProcessPoolExecutor(1, mp_context=get_context("spawn"),
                           initializer=watch_parent if watched else None,
                           initargs=(0.2,) if watched else ())
import os
print(pool.submit(os.getpid).result(), flush=True)
pool.submit(time.sleep, 600)
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie nobody reaps counts as gone where /proc says so)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    status = Path(f"/proc/{pid}/status")
    try:
        return "\nState:\tZ" not in status.read_text()
    except FileNotFoundError:
        return not Path("/proc/self").exists()


def _orphan(watched: bool) -> int:
    """Starts an owner process with one spawned worker, kills the owner with SIGKILL, and
    returns the worker's process id."""
    owner = subprocess.Popen([sys.executable, "-W", "ignore::UserWarning", "-c", OWNER,
                              "watched" if watched else "bare"], stdout=subprocess.PIPE,
                             text=True)  # -W: the killed owner's semaphores, not ours
    worker = int(owner.stdout.readline())
    assert _alive(worker)
    owner.send_signal(signal.SIGKILL)
    owner.wait(30)
    owner.stdout.close()
    return worker


def test_worker_ends_with_its_killed_owner():
    worker = _orphan(watched=True)
    deadline = time.monotonic() + 30
    while _alive(worker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(worker), "the watched worker outlived its owner by 30 s"


def test_unwatched_worker_is_orphaned():
    """The control: without :func:`watch_parent` the same worker runs on."""
    worker = _orphan(watched=False)
    try:
        time.sleep(1.5)
        assert _alive(worker)
    finally:
        os.kill(worker, signal.SIGKILL)


def test_poll_must_be_positive():
    with pytest.raises(ValueError, match="poll_s"):
        watch_parent(0.0)
