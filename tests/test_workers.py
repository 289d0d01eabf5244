"""A pool's workers end with the process that owns the pool (:mod:`wtml.workers`)."""

import os
import signal
import subprocess
import sys
import time

import pytest

from wtml.workers import gone, watch_parent

OWNER = """
import os, sys, time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from wtml.workers import watch_parent
watched = sys.argv[1] == "watched"
pool = ProcessPoolExecutor(1, mp_context=get_context(sys.argv[2]),
                           initializer=watch_parent if watched else None,
                           initargs=(os.getpid(), 0.2) if watched else ())
print(pool.submit(os.getpid).result(), flush=True)
pool.submit(time.sleep, 600)
time.sleep(600)
"""


def _orphan(watched: bool, folder, method: str = "spawn") -> int:
    """Starts an owner process with one worker (started by ``method``), kills the owner with
    SIGKILL, and returns the worker's process id. The owner's temporary files (a fork
    server's socket, which a killed owner leaves) go to ``folder``."""
    owner = subprocess.Popen([sys.executable, "-W", "ignore::UserWarning", "-c", OWNER,
                              "watched" if watched else "bare", method], stdout=subprocess.PIPE,
                             text=True,  # -W: the killed owner's semaphores, not ours
                             env=os.environ | {"TMPDIR": str(folder)})
    worker = int(owner.stdout.readline())
    assert not gone(worker)
    owner.send_signal(signal.SIGKILL)
    owner.wait(30)
    owner.stdout.close()
    return worker


@pytest.mark.parametrize("method", ["spawn", "forkserver"])
def test_worker_ends_with_its_killed_owner(method, tmp_path):
    """Spawned (texture-scale's pool) and forked from a fork server (the main job's lanes:
    the worker's parent is the server, which outlives the owner while the worker lives)."""
    worker = _orphan(True, tmp_path, method)
    deadline = time.monotonic() + 30
    while not gone(worker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert gone(worker), "the watched worker outlived its owner by 30 s"


@pytest.mark.parametrize("method", ["spawn", "forkserver"])
def test_unwatched_worker_is_orphaned(method, tmp_path):
    """The control: without :func:`watch_parent` the same worker runs on."""
    worker = _orphan(False, tmp_path, method)
    try:
        time.sleep(1.5)
        assert not gone(worker)
    finally:
        os.kill(worker, signal.SIGKILL)


def test_poll_must_be_positive():
    with pytest.raises(ValueError, match="poll_s"):
        watch_parent(poll_s=0.0)


def test_gone_sees_a_zombie_and_a_reaped_child():
    assert not gone(os.getpid())
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    deadline = time.monotonic() + 30
    while not gone(child.pid) and time.monotonic() < deadline:  # ended, not yet reaped
        time.sleep(0.05)
    assert gone(child.pid)
    child.wait(30)
    assert gone(child.pid)
