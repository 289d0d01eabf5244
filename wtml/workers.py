"""Worker processes that end with the process that owns their pool.

A pool's workers block on its call queue or run a long job; when the process that owns the
pool is killed (``kill PID``, an out-of-memory kill, a scheduler's time limit) nothing tells
them, and they run on as orphans, holding their memory and cores. (Killing ``wtml bench
texture-scale`` once left its two generation workers running for 75 minutes, ~0.7 GB each.)
:func:`watch_parent`, a pool's ``initializer``, starts a daemon thread in the worker that
ends it once the owner is gone.

The owner's process id is passed in, not read as the worker's parent: a worker forked from a
fork server (the main job's lanes) is the server's child, and the server outlives the owner
while any worker lives, since each worker holds the pipe whose closing would tell the server
that its owner is gone.
"""

import os
import threading
import time
from pathlib import Path

POLL_S = 1.0
"""Seconds between two looks at the owner."""


def gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (a zombie not yet reaped counts as ended where
    /proc says so)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # it runs, as another user
        return False
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state == "Z"


def _watch(owner: int, parent: int, poll_s: float) -> None:
    while True:
        if os.getppid() != parent or gone(owner):
            os._exit(1)  # no cleanup: the process that would collect our results is gone
        time.sleep(poll_s)


def watch_parent(owner: int | None = None, poll_s: float = POLL_S) -> None:
    """Ends this process within ``poll_s`` seconds of the end of ``owner`` (a process id;
    None: this process's parent) or of its parent, whichever ends first (a daemon thread).

    Use as a ``ProcessPoolExecutor``'s ``initializer`` with ``initargs=(os.getpid(),)``.
    ``poll_s`` > 0, or ValueError. (A process id reused within ``poll_s`` of the owner's end
    would keep the worker: rare enough to leave.)"""
    if not poll_s > 0:
        raise ValueError(f"poll_s: must be > 0 seconds, got {poll_s}")
    parent = os.getppid()
    threading.Thread(target=_watch, args=(parent if owner is None else owner, parent, poll_s),
                     daemon=True, name="watch-parent").start()
