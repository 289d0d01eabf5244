"""Timing of a predictor, the same way for every method: p50 latency and throughput.

Each measurement stops at its repeat count or once it has run ``budget_s`` seconds (at
least one call), and its warm-up once it has run a third of that, so a slow method (the
physics inversion takes ~7 s per call at batch 4096) does not hold up a benchmark; the median
is robust to the count. Also :func:`duration`, the one way wtml prints a wall-clock time
(training's epoch lines, the main job's stages)."""

from __future__ import annotations

import time

import numpy as np


def _median_call(predictor, ze, repeats: int, warmup: int, budget_s: float) -> float:
    args = ze if isinstance(ze, tuple) else (ze,)
    start = time.perf_counter()
    for _ in range(warmup):
        predictor.predict(*args)
        if time.perf_counter() - start > budget_s / 3:
            break
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < repeats and (not times or time.perf_counter() - start < budget_s):
        t0 = time.perf_counter()
        predictor.predict(*args)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def latency_p50(predictor, ze_one, repeats: int, budget_s: float = 3.0) -> float:
    """Median seconds of one ``predict`` call at batch 1 (after 20 warm-up calls);
    ``ze_one`` an array, or a tuple of the predictor's arguments (e.g. ``(ze, ref)``)."""
    return _median_call(predictor, ze_one, repeats, 20, budget_s)


def throughput(predictor, ze_batch, repeats: int, budget_s: float = 3.0) -> float:
    """Samples per second at the batch size of ``ze_batch`` (an array or a tuple of
    arguments, as for :func:`latency_p50`; median over the calls)."""
    n = len(ze_batch[0] if isinstance(ze_batch, tuple) else ze_batch)
    return n / _median_call(predictor, ze_batch, repeats, 1, budget_s)


def duration(seconds: float) -> str:
    """``12.3 s`` or ``4 min 05 s``."""
    if not seconds < 60:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s" if seconds == seconds else "?"
    return f"{seconds:.1f} s"
