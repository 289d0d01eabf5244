"""Worker processes that end with the process that started them.

A pool's workers block on its call queue or run a long job; when the process that owns the
pool is killed (``kill PID``, an out-of-memory kill, a scheduler's time limit) nothing tells
them, and they run on as orphans, holding their memory and cores. (Killing ``wtml bench
texture-scale`` once left its two generation workers running for 75 minutes, ~0.7 GB each.)
:func:`watch_parent`, a pool's ``initializer``, starts a daemon thread in the worker that
ends it once its parent is gone: the worker is re-parented then, so its parent's process id
changes (to 1 or to a subreaper's). Under a fork server the parent is the server, which exits
when the process that started it does.
"""

import os
import threading

POLL_S = 1.0
"""Seconds between two looks at the parent's process id."""


def _watch(parent: int, poll_s: float) -> None:
    while True:
        if os.getppid() != parent:
            os._exit(1)  # no cleanup: the process that would collect our results is gone
        threading.Event().wait(poll_s)


def watch_parent(poll_s: float = POLL_S) -> None:
    """Ends this process within ``poll_s`` seconds of its parent's end (a daemon thread).

    Use as a ``ProcessPoolExecutor``'s ``initializer``. ``poll_s`` > 0, or ValueError."""
    if not poll_s > 0:
        raise ValueError(f"poll_s: must be > 0 seconds, got {poll_s}")
    threading.Thread(target=_watch, args=(os.getppid(), poll_s), daemon=True,
                     name="watch-parent").start()
