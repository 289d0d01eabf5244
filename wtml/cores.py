"""How many cores this process may compute on: the one answer every threaded part of wtml
(the stepper's blocks, onnxruntime sessions, the peers' jobs) takes its default from."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

THREADS_ENV = "WTML_THREADS"
"""An environment variable that caps :func:`available_cores` (the main job's lanes run
one thread each: :func:`wtml.pipeline.run_all`)."""


def available_cores() -> int:
    """The cores this process may run on (its affinity), at most ``$WTML_THREADS`` where that
    is set to a positive integer.

    Raises:
        ValueError: ``$WTML_THREADS`` is set but not a positive integer.
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    cap = os.environ.get(THREADS_ENV, "").strip()
    if not cap:
        return cores
    if not cap.isdigit() or int(cap) < 1:
        raise ValueError(f"${THREADS_ENV}: must be a positive integer, got {cap!r}")
    return min(cores, int(cap))


@contextlib.contextmanager
def capped(threads: int | None) -> Iterator[None]:
    """Within the block, :func:`available_cores` is at most ``threads`` (None: as it was):
    ``$WTML_THREADS`` set to it, replacing any value it had, and put back after, also when
    the block raises. For a command's process (it changes the process's environment).

    Raises:
        ValueError: ``threads`` is below 1.
    """
    if threads is None:
        yield
        return
    if int(threads) < 1:
        raise ValueError(f"threads: must be at least 1, got {threads}")
    before = os.environ.get(THREADS_ENV)
    os.environ[THREADS_ENV] = str(int(threads))
    try:
        yield
    finally:
        if before is None:
            del os.environ[THREADS_ENV]
        else:
            os.environ[THREADS_ENV] = before
