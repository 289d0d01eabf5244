"""Timing of a predictor, the same way for every method: p50 latency and throughput."""

from __future__ import annotations

import time

import numpy as np


def latency_p50(predictor, ze_one: np.ndarray, repeats: int) -> float:
    """Median seconds of one ``predict`` call at batch 1."""
    for _ in range(20):
        predictor.predict(ze_one)
    times = np.empty(repeats)
    for k in range(repeats):
        t0 = time.perf_counter()
        predictor.predict(ze_one)
        times[k] = time.perf_counter() - t0
    return float(np.median(times))


def throughput(predictor, ze_batch: np.ndarray, repeats: int) -> float:
    """Samples per second at the batch size of ``ze_batch`` (median over repeats)."""
    predictor.predict(ze_batch)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        predictor.predict(ze_batch)
        times.append(time.perf_counter() - t0)
    return len(ze_batch) / float(np.median(times))
