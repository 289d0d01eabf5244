"""Timing helpers on a clock the test drives (no wall-clock timing in unit tests): the
side-by-side ratio of two methods holds through a drift of the machine that one measurement
after the other takes as a difference."""

from __future__ import annotations

import numpy as np
import pytest

from wtml.bench.timing import duration, latency_p50, paired_ratio


class Clock:
    """Seconds that advance only when a fake predictor runs: ``cost`` of the predictor times
    the machine's slowness, which ``drift`` (per second of clock) raises as time passes."""

    def __init__(self, drift: float = 0.0) -> None:
        self.now, self.drift = 0.0, drift

    def __call__(self) -> float:
        return self.now

    def run(self, cost: float) -> None:
        self.now += cost * (1 + self.drift * self.now)


class Fake:
    def __init__(self, clock: Clock, cost: float) -> None:
        self.clock, self.cost = clock, cost

    def predict(self, *args) -> dict:
        self.clock.run(self.cost)
        return {}


def test_the_ratio_of_two_methods_side_by_side_is_their_cost_ratio():
    clock = Clock()
    mid, low, high = paired_ratio(Fake(clock, 1e-3), Fake(clock, 0.5e-3), (np.zeros(1),),
                                  clock=clock)
    assert mid == pytest.approx(0.5) and low == pytest.approx(0.5) and high == pytest.approx(0.5)


def test_a_drifting_machine_moves_sequential_timing_but_not_the_paired_ratio():
    """The machine slows by 5 % per second of clock: two equal methods timed one after the
    other differ; side by side their ratio stays within a hair of 1."""
    clock = Clock(drift=0.05)
    a, b = Fake(clock, 1e-2), Fake(clock, 1e-2)
    first = latency_p50(a, np.zeros(1), 200, budget_s=100.0, clock=clock)
    second = latency_p50(b, np.zeros(1), 200, budget_s=100.0, clock=clock)
    assert second / first > 1.05  # the drift, read as a difference
    mid, low, high = paired_ratio(a, b, np.zeros(1), rounds=9, calls=10, budget_s=100.0,
                                  clock=clock)
    assert abs(mid - 1) < 0.01 and low < 1 < high


def test_the_rounds_stop_at_the_budget_but_never_below_three():
    clock = Clock()
    slow = Fake(clock, 10.0)
    paired_ratio(slow, slow, np.zeros(1), rounds=50, calls=1, budget_s=1.0, clock=clock)
    assert clock.now == pytest.approx(3 * 2 * 10.0)  # three rounds of one call each


def test_duration_reads_like_a_person_writes_it():
    assert duration(12.34) == "12.3 s"
    assert duration(245.0) == "4 min 05 s"
    assert duration(float("nan")) == "?"


def test_another_process_busy_while_timing_is_seen_and_said(tmp_path):
    """A child spinning one core while the bench runs counts as another process's load (its
    CPU is not the bench's own until it is waited for); the report warns above BUSY_SHARE and
    says the share below it; without /proc/stat (not Linux) there is no verdict."""
    import os
    import subprocess
    import sys
    import time

    from wtml.bench.frontier import busy_lines
    from wtml.bench.timing import BUSY_SHARE, busy_elsewhere, cpu_snapshot

    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)
        start = cpu_snapshot()
        time.sleep(1.0)
        end = cpu_snapshot()
    finally:
        spin.kill()
        spin.wait()
    share = busy_elsewhere(start, end)
    assert end[3] == len(os.sched_getaffinity(0)) and share > 0.6 / end[3]
    assert busy_elsewhere(start, start) is None and busy_elsewhere(None, end) is None
    assert cpu_snapshot(tmp_path / "stat") is None  # no file
    (tmp_path / "stat").write_text("cpu  1 2 3\ncpu0 x y\n")
    assert cpu_snapshot(tmp_path / "stat") is None  # not /proc/stat's form
    assert busy_elsewhere((10.0, 0.0, 0.0, 2), (11.0, 1.0, 1.0, 2)) == 0.0  # all its own
    assert busy_elsewhere((10.0, 0.0, 0.0, 2), (12.0, 1.0, 1.0, 2)) == 0.5
    assert busy_elsewhere((10.0, 0.0, 0.0, 2), (19.0, 1.0, 1.0, 2)) == 1.0  # clipped
    busy = "\n".join(busy_lines({"busy_elsewhere": 2 * BUSY_SHARE, "cores": 2}))
    assert "**Busy machine:**" in busy and "Re-run it alone" in busy and "2 cores" in busy
    calm = "\n".join(busy_lines({"busy_elsewhere": BUSY_SHARE / 2, "cores": 2}))
    assert "Busy" not in calm and "other processes kept" in calm
    assert busy_lines({"busy_elsewhere": None}) == []
