"""How the main job's slices share its lanes: the order they start in (:func:`lane_order`).

The lanes are a pool of processes that takes the slices in order, each lane the next slice
when it frees; each slice ends with its ``bench`` stage, which the lanes take in turns (a
file lock: two benches side by side held 3.1 GB together).
Longest first is not the best order under that lock: the two longest slices' benches meet
at about the same time and one waits for the other (89 s in the main job of 27 Nov).
:func:`makespan` replays the pool and the lock on each slice's measured seconds, and
:func:`lane_order` takes the order whose replay ends first. The replay hands the lock to the
bench that asked first; ``flock`` wakes its waiters in no set order, so the replay is exact
where at most one bench waits (two lanes, the default) and an estimate beyond. A warm-up
(``warm_s``: the tasks' JIT kernels compiled ahead, :func:`wtml.pipeline.run_all`) holds the
first lane from the start; the slices take the others, then that one once it frees.
"""

from __future__ import annotations

import heapq
from itertools import permutations


def makespan(order: list[str], work_s: dict[str, float], bench_s: dict[str, float],
             lanes: int, warm_s: float = 0.0) -> float:
    """Seconds until the last of ``order``'s slices ends, when ``lanes`` lanes take them in
    that order and their benches take turns.

    Args:
        order: slice names, in the order the pool takes them.
        work_s: each slice's seconds in all, its bench included (and no wait).
        bench_s: the seconds of each slice's bench, its last stage (≤ its ``work_s``).
        lanes: lanes side by side (≥ 1).
        warm_s: seconds of a warm-up that the first lane runs before any slice (0: none).
    """
    pending = list(order)
    events: list[tuple[float, int, str, str]] = []  # (time, tie-break, kind, slice)
    count = 0

    def start(name: str, t: float) -> None:
        nonlocal count
        heapq.heappush(events, (t + work_s[name] - bench_s[name], count, "bench", name))
        count += 1

    for _ in range(min(lanes - (warm_s > 0), len(pending))):
        start(pending.pop(0), 0.0)
    if warm_s > 0:  # the warm-up's lane frees then: the job lasts at least as long
        heapq.heappush(events, (warm_s, count, "free", ""))
        count += 1
    holder, waiting, end = None, [], 0.0
    while events:
        t, _, kind, name = heapq.heappop(events)
        if kind == "free":
            end = max(end, t)
            if pending:
                start(pending.pop(0), t)
            continue
        if kind == "bench":
            if holder is None:
                holder = name
                heapq.heappush(events, (t + bench_s[name], count, "done", name))
                count += 1
            else:
                waiting.append(name)
            continue
        end, holder = max(end, t), None
        if waiting:
            holder = waiting.pop(0)
            heapq.heappush(events, (t + bench_s[holder], count, "done", holder))
            count += 1
        if pending:
            start(pending.pop(0), t)
    return end


def lane_order(work_s: dict[str, float], bench_s: dict[str, float], lanes: int,
               warm_s: float = 0.0) -> list[str]:
    """The order of the slices (``work_s``' keys) whose :func:`makespan` (with a warm-up of
    ``warm_s`` first) is the shortest on ``lanes`` lanes (to a microsecond: sums in another
    order differ in the last bit); of equal ones, the first in longest-first order. Every
    order is tried (the main job has four slices: 24)."""
    longest_first = sorted(work_s, key=lambda name: -work_s[name])
    return list(min(permutations(longest_first),
                    key=lambda order: round(makespan(list(order), work_s, bench_s, lanes,
                                                     warm_s), 6)))
