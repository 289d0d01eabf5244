"""How many cores this process may compute on: the one answer every threaded part of wtml
(the stepper's blocks, onnxruntime sessions, the peers' jobs, the main job's lanes) takes its
default from: the process's affinity, a container's CPU quota (Linux cgroups) and
``$WTML_THREADS``, whichever is least."""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterator
from pathlib import Path

THREADS_ENV = "WTML_THREADS"
"""An environment variable that caps :func:`available_cores` (the main job's lanes run
one thread each: :func:`wtml.pipeline.run_all`)."""


CGROUP_ROOT = Path("/sys/fs/cgroup")
"""Where Linux mounts the control groups (v2: one tree; v1: a tree per controller)."""
PROC_CGROUP = Path("/proc/self/cgroup")
"""This process's control groups, one ``id:controllers:path`` line each."""


def _quota(path: Path) -> float | None:
    """The CPU quota (cores) a cgroup folder sets, or None where it sets none or cannot be
    read: v2's ``cpu.max`` (``"<quota> <period>"`` or ``"max <period>"``), v1's
    ``cpu.cfs_quota_us`` (-1: none) over ``cpu.cfs_period_us``."""
    try:
        if (path / "cpu.max").is_file():
            quota, period = (path / "cpu.max").read_text().split()[:2]
        else:
            quota = (path / "cpu.cfs_quota_us").read_text().strip()
            period = (path / "cpu.cfs_period_us").read_text().strip()
        quota_us, period_us = float(quota), float(period)
    except (OSError, ValueError):
        return None  # "max", a missing file, an unreadable one: no quota here
    if not (0 < quota_us < math.inf and 0 < period_us < math.inf):
        return None  # -1 (v1's "none"), 0, inf, nan
    return quota_us / period_us


def _groups(root: Path, proc: Path) -> list[Path]:
    """The folders of this process's CPU control group and every group above it: v2's
    unified tree (a line ``0::<path>``) and v1's cpu controller (``<id>:<controllers with
    cpu>:<path>``, mounted under ``root`` by its controllers' names, e.g. ``cpu,cpuacct``)."""
    found = []
    for line in proc.read_text().splitlines():
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        key, controllers, where = fields
        if key == "0" and controllers == "":
            base = root
        elif "cpu" in controllers.split(","):
            base = next((root / d for d in (controllers, "cpu", "cpu,cpuacct", "cpuacct,cpu")
                         if (root / d).is_dir()), None)
            if base is None:
                continue
        else:
            continue
        parts = [p for p in where.strip().split("/") if p and p != ".."]
        found += [base.joinpath(*parts[:depth]) for depth in range(len(parts) + 1)]
    return found


def cgroup_cores(root: Path = CGROUP_ROOT, proc: Path = PROC_CGROUP) -> float | None:
    """The CPU quota of this process's control group and every group above it, the least
    (cores, fractional), or None where none is set or the files cannot be read (not Linux,
    no permission, not text): never an error. A container started with ``--cpus 2`` on a
    64-core host has its affinity on all 64 and this quota of 2: threads beyond it wait for
    the scheduler's next period instead of computing. Both cgroup versions; a container's
    own group is mounted at the root (its path in ``proc`` may still name the host's), so
    the root is read too."""
    try:
        quotas = [q for q in map(_quota, _groups(root, proc)) if q is not None]
    except (OSError, ValueError):  # an unreadable or undecodable file, a folder we may not see
        return None
    return min(quotas) if quotas else None


def available_cores() -> int:
    """The cores this process may run on: its affinity, at most its control group's CPU quota
    rounded up (:func:`cgroup_cores`; loky and joblib round it alike) and at most
    ``$WTML_THREADS`` where that is set to a positive integer.

    Raises:
        ValueError: ``$WTML_THREADS`` is set but not a positive integer.
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    quota = cgroup_cores()
    if quota is not None:
        cores = max(1, min(cores, math.ceil(quota)))
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
