"""The group bootstrap of the benches: coverage when samples come in correlated groups."""

import numpy as np
import pytest

from wtml.bench.resampling import effective_count, group_interval


def clustered(rng, groups=40, per_group=8, mean=0.85, concentration=3.0):
    """Correctness of ``per_group`` windows of each of ``groups`` specimens: each specimen's
    own rate drawn from a beta of the given mean (small concentration: strongly grouped)."""
    rate = rng.beta(mean * concentration, (1 - mean) * concentration, groups)
    values = (rng.random((groups, per_group)) < rate[:, None]).astype(float).ravel()
    return values, np.repeat(np.arange(groups), per_group)


def test_group_interval_covers_the_true_mean_at_its_level_and_windows_alone_do_not():
    """300 benches of 40 specimens x 8 windows: the group interval holds the population mean
    (0.85) about 95 % of the time; treating the windows as independent covers far less."""
    rng = np.random.default_rng(1)
    hits = {"groups": 0, "windows": 0}
    trials = 300
    for t in range(trials):
        values, groups = clustered(rng)
        for key, g in (("groups", groups), ("windows", np.arange(len(values)))):
            low, high = group_interval(values, g, draws=1000, seed=t)
            hits[key] += low <= 0.85 <= high
    assert 0.90 <= hits["groups"] / trials <= 0.99, hits
    assert hits["windows"] / trials < 0.8, hits


def test_group_interval_limits():
    """Constant values give a point; independent 0/1 samples give the binomial interval."""
    assert group_interval(np.full(12, 0.75), np.arange(12) // 3) == (0.75, 0.75)
    rng = np.random.default_rng(2)
    values = (rng.random(4000) < 0.9).astype(float)
    low, high = group_interval(values, np.arange(4000))
    half = 1.96 * np.sqrt(values.mean() * (1 - values.mean()) / 4000)
    assert abs(low - (values.mean() - half)) < 2e-3 and abs(high - (values.mean() + half)) < 2e-3


def test_group_interval_refuses_bad_input():
    with pytest.raises(ValueError, match="same length"):
        group_interval([1.0, 0.0], [0])
    with pytest.raises(ValueError, match="level must be in"):
        group_interval([1.0, 0.0], [0, 1], level=1.5)


def test_answers_that_share_their_errors_are_worth_their_groups():
    hit = np.tile([1.0, 0.0, 1.0, 1.0], 25)  # 100 answers, 75 % covered
    # each answer its own group: the binomial's n (less the variance's one degree)
    assert effective_count(hit, np.arange(100)) == pytest.approx(99)
    # 20 groups of 5 identical answers: worth 20 groups (less one), not 100 answers
    same = np.repeat(np.tile([1.0, 0.0, 1.0, 1.0], 5), 5)
    assert effective_count(same, np.repeat(np.arange(20), 5)) == pytest.approx(19)
    # groups that agree everywhere, or one group: as many as the groups
    assert effective_count(np.ones(50), np.repeat(np.arange(10), 5)) == 10
    assert effective_count(hit, np.zeros(100)) == 1
    # never narrower than the binomial: answers balanced within each group (no spread
    # between groups), or nearly so (spread of 2 in 25 groups: the ratio alone says 900)
    groups = np.repeat(np.arange(25), 4)
    assert effective_count(hit, groups) == 100
    nearly = hit.copy()
    nearly[[1, 6]] = 1.0, 0.0  # group 0 covers 4 of 4, group 1 covers 2 of 4
    assert effective_count(nearly, groups) == 100
    # a 95 % interval's few misses cannot show how they cluster: the groups, until they
    # show in MIN_GROUPS_SHOWN of them (five isolated misses: as many as the answers)
    four = np.repeat(np.arange(48), 4)
    few = np.ones(192)
    assert effective_count(few, four) == 48
    few[[0, 4, 8, 12]] = 0.0
    assert effective_count(few, four) == 48
    few[16] = 0.0
    assert effective_count(few, four) > 150
    # groups of unequal size: worth fewer than their number (4 of 10 windows, 44 of 4)
    uneven = np.concatenate([np.repeat(np.arange(4), 10), np.repeat(np.arange(4, 48), 4)])
    assert effective_count(np.ones(216), uneven) == pytest.approx(216**2 / (4 * 100 + 44 * 16))


def test_the_count_refuses_what_it_cannot_count():
    with pytest.raises(ValueError, match="one label per answer"):
        effective_count(np.ones(4), None)
    with pytest.raises(ValueError, match="one label per answer"):
        effective_count(np.ones(4), [0, 1])
    with pytest.raises(ValueError, match="leave out rows without one"):
        effective_count([1.0, np.nan, 0.0], [0, 1, 2])
