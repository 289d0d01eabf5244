"""Timing of a predictor, the same way for every method: p50 latency and throughput.

Each measurement stops at its repeat count or once it has run ``budget_s`` seconds (at
least one call), and its warm-up once it has run a third of that, so a slow method (the
physics inversion takes ~7 s per call at batch 4096) does not hold up a benchmark; the median
is robust to the count. Two methods compared side by side: :func:`paired_ratio`. Whether
other processes shared the machine while it was timed: :func:`cpu_snapshot` and
:func:`busy_elsewhere`. Also
:func:`duration`, the one way wtml prints a wall-clock time
(training's epoch lines, the main job's stages)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

Clock = Callable[[], float]
"""Seconds (``time.perf_counter``; a test drives its own)."""
BUSY_SHARE = 0.1
"""The share of the machine's cores that other processes may keep busy while a bench is timed
before its report calls the machine busy (beside a unit-test run, fluid's throughput read
5.1e5/s against 1.4e6/s alone)."""


def _median_call(predictor, ze, repeats: int, warmup: int, budget_s: float,
                 clock: Clock = time.perf_counter) -> float:
    args = ze if isinstance(ze, tuple) else (ze,)
    start = clock()
    for _ in range(warmup):
        predictor.predict(*args)
        if clock() - start > budget_s / 3:
            break
    times: list[float] = []
    start = clock()
    while len(times) < repeats and (not times or clock() - start < budget_s):
        t0 = clock()
        predictor.predict(*args)
        times.append(clock() - t0)
    return float(np.median(times))


def latency_p50(predictor, ze_one, repeats: int, budget_s: float = 3.0,
                clock: Clock = time.perf_counter) -> float:
    """Median seconds of one ``predict`` call at batch 1 (after 20 warm-up calls);
    ``ze_one`` an array, or a tuple of the predictor's arguments (e.g. ``(ze, ref)``)."""
    return _median_call(predictor, ze_one, repeats, 20, budget_s, clock)


def throughput(predictor, ze_batch, repeats: int, budget_s: float = 3.0,
               clock: Clock = time.perf_counter) -> float:
    """Samples per second at the batch size of ``ze_batch`` (an array or a tuple of
    arguments, as for :func:`latency_p50`; median over the calls)."""
    n = len(ze_batch[0] if isinstance(ze_batch, tuple) else ze_batch)
    return n / _median_call(predictor, ze_batch, repeats, 1, budget_s, clock)


def paired_ratio(first, second, args, *, rounds: int = 9, calls: int = 10,
                 budget_s: float = 3.0, clock: Clock = time.perf_counter
                 ) -> tuple[float, float, float]:
    """How long ``second.predict(*args)`` takes over ``first.predict(*args)``, timed side by
    side: in each round ``calls`` calls of one then ``calls`` of the other (the order
    alternating between rounds), the ratio of their medians. A drift of the machine within a
    round falls on both alike, where two measurements one after the other (as
    :func:`latency_p50` of each) take it as a difference: on this shared 2-core machine those
    verdicts disagreed between runs an hour apart. Stops after ``rounds`` rounds or once
    ``budget_s`` seconds have run (at least 3 rounds).

    Returns:
        the median of the rounds' ratios and its 25th and 75th percentiles.
    """
    args = args if isinstance(args, tuple) else (args,)

    def median_call(predictor) -> float:
        times = []
        for _ in range(calls):
            t0 = clock()
            predictor.predict(*args)
            times.append(clock() - t0)
        return float(np.median(times))

    ratios: list[float] = []
    start = clock()
    while len(ratios) < rounds and (len(ratios) < 3 or clock() - start < budget_s):
        if len(ratios) % 2:
            b, a = median_call(second), median_call(first)
        else:
            a, b = median_call(first), median_call(second)
        ratios.append(b / a)
    low, mid, high = np.percentile(ratios, [25, 50, 75])
    return float(mid), float(low), float(high)


def duration(seconds: float) -> str:
    """``12.3 s`` or ``4 min 05 s``."""
    if not seconds < 60:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s" if seconds == seconds else "?"
    return f"{seconds:.1f} s"


def cpu_snapshot(stat: Path = Path("/proc/stat")) -> tuple[float, float, float, int] | None:
    """``(the busy CPU seconds of the cores this process may run on, this process's and its
    finished children's CPU seconds, wall-clock seconds, those cores' count)`` now, or None
    where ``stat`` (Linux's ``/proc/stat``) cannot be read. Busy: user, nice, system, irq,
    softirq and steal time of each ``cpuN`` line in the process's affinity."""
    mine = set(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    try:
        rows = [line.split() for line in stat.read_text().splitlines()]
        cores = [r for r in rows if r and r[0][3:].isdigit() and r[0].startswith("cpu")
                 and (mine is None or int(r[0][3:]) in mine)]
        busy = sum(int(r[i]) for r in cores for i in (1, 2, 3, 6, 7, 8))
    except (OSError, ValueError, IndexError):
        return None
    if not cores:
        return None
    own = os.times()
    spent = own.user + own.system + own.children_user + own.children_system
    return busy / os.sysconf("SC_CLK_TCK"), spent, time.monotonic(), len(cores)


def busy_elsewhere(start, end) -> float | None:
    """The share of the snapshots' cores that other processes kept busy between two
    snapshots of :func:`cpu_snapshot`: ``(those cores' busy time - own) / (wall × cores)``,
    clipped to [0, 1]; None where either is None or no time passed."""
    if start is None or end is None or end[2] <= start[2]:
        return None
    other = (end[0] - start[0]) - (end[1] - start[1])
    return min(1.0, max(0.0, other / ((end[2] - start[2]) * end[3])))
