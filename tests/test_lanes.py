"""The main job's order of slices (:mod:`wtml.lanes`): the replay of the pool and the bench
lock against hand-worked schedules, and the order it picks against longest first."""

from __future__ import annotations

import pytest

from wtml.lanes import lane_order, makespan

# the main job of 27 Nov (s, one thread): texture, radial, onset, fluid and their benches
WORK = {"texture": 341.0, "radial": 316.0, "onset": 190.0, "fluid": 50.0}
BENCH = {"texture": 174.0, "radial": 63.0, "onset": 45.0, "fluid": 21.0}


def test_one_lane_is_the_sum():
    assert makespan(list(WORK), WORK, BENCH, 1) == pytest.approx(sum(WORK.values()))


def test_longest_first_replays_the_wait_the_main_job_measured():
    """Texture's bench holds 167-341 s; radial's asks at 253 s and waits to 341 s (the 89 s
    of 27 Nov), ends at 404 s; onset starts in texture's lane at 341 s and ends at 531 s."""
    order = ["texture", "radial", "onset", "fluid"]
    assert makespan(order, WORK, BENCH, 2) == pytest.approx(531.0)


def test_a_bench_waits_only_when_another_holds_the_lock():
    """Both ask at 90 s: the second waits to 100 s. Then b's bench at 40-50 s: no wait."""
    work, bench = {"a": 100.0, "b": 100.0}, {"a": 10.0, "b": 10.0}
    assert makespan(["a", "b"], work, bench, 2) == pytest.approx(110.0)
    work = {"a": 100.0, "b": 50.0}
    assert makespan(["a", "b"], work, bench, 2) == pytest.approx(100.0)


def test_the_chosen_order_ends_no_later_than_any_other():
    order = lane_order(WORK, BENCH, 2)
    assert sorted(order) == sorted(WORK)
    best = makespan(order, WORK, BENCH, 2)
    assert best < makespan(["texture", "radial", "onset", "fluid"], WORK, BENCH, 2)
    assert best == pytest.approx(506.0)  # texture | onset then radial; fluid after texture


def test_equal_orders_keep_longest_first():
    work = {"a": 10.0, "b": 20.0}
    assert lane_order(work, {"a": 0.0, "b": 0.0}, 1) == ["b", "a"]
    # on one lane every order ends at the sum; in tenths of a second, sums in different
    # orders differ in the last bit
    work = {"a": 0.7, "b": 0.6, "c": 0.3, "d": 0.1}
    bench = {"a": 0.1, "b": 0.2, "c": 0.1, "d": 0.1}
    assert lane_order(work, bench, 1) == ["a", "b", "c", "d"]


def test_a_warm_up_holds_the_first_lane_from_the_start():
    """a starts at 0 in the free lane, its bench 90-100 s; b waits for the warm-up's lane
    (30 s): its bench 70-80 s. In the other order b's bench is 40-50 s and a, from 30 s,
    asks at 120 s. On one lane the warm-up comes before the sum."""
    work, bench = {"a": 100.0, "b": 50.0}, {"a": 10.0, "b": 10.0}
    assert makespan(["a", "b"], work, bench, 2, warm_s=30.0) == pytest.approx(100.0)
    assert makespan(["b", "a"], work, bench, 2, warm_s=30.0) == pytest.approx(130.0)
    assert lane_order(work, bench, 2, warm_s=30.0) == ["a", "b"]
    assert makespan(["a", "b"], work, bench, 1, warm_s=30.0) == pytest.approx(180.0)
    assert makespan(["a"], work, bench, 2, warm_s=130.0) == pytest.approx(130.0)
