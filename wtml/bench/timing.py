"""Timing of a predictor, the same way for every method: p50 latency and throughput.

Each measurement stops at its repeat count or once it has run ``budget_s`` seconds (at
least one call), and its warm-up once it has run a third of that, so a slow method (the
physics inversion takes ~7 s per call at batch 4096) does not hold up a benchmark; the median
is robust to the count."""

from __future__ import annotations

import time

import numpy as np


def _median_call(predictor, ze: np.ndarray, repeats: int, warmup: int, budget_s: float
                 ) -> float:
    start = time.perf_counter()
    for _ in range(warmup):
        predictor.predict(ze)
        if time.perf_counter() - start > budget_s / 3:
            break
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < repeats and (not times or time.perf_counter() - start < budget_s):
        t0 = time.perf_counter()
        predictor.predict(ze)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def latency_p50(predictor, ze_one: np.ndarray, repeats: int, budget_s: float = 3.0) -> float:
    """Median seconds of one ``predict`` call at batch 1 (after 20 warm-up calls)."""
    return _median_call(predictor, ze_one, repeats, 20, budget_s)


def throughput(predictor, ze_batch: np.ndarray, repeats: int, budget_s: float = 3.0) -> float:
    """Samples per second at the batch size of ``ze_batch`` (median over the calls)."""
    return len(ze_batch) / _median_call(predictor, ze_batch, repeats, 1, budget_s)
