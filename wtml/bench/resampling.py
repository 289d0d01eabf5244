"""Confidence intervals of a bench mean when the samples come in groups (windows of one
specimen): the group bootstrap (:func:`group_interval`), and what a share's samples are worth
in independent ones (:func:`effective_count`) for a binomial interval, which stays an interval
at a share of 0 or 1 where a bootstrap collapses to a point (an interval's coverage of 100 %).
Windows of one specimen share its friction and grains, so they are not independent draws;
resampling windows alone would make the interval too narrow by about the square root of the
windows per specimen."""

from __future__ import annotations

import numpy as np


def group_interval(values, groups, *, level: float = 0.95, draws: int = 4000,
                   seed: int = 0) -> tuple[float, float]:
    """Percentile-bootstrap interval of ``mean(values)``, resampling whole groups.

    Args:
        values: per sample, ``(n,)`` (1/0 for correct/wrong; a difference of two methods'
            correctness on the same samples gives the paired interval of their difference).
        groups: the group of each sample, ``(n,)`` (any hashable labels).
        level: the interval's coverage, in (0, 1).
        draws: bootstrap resamples of the groups.

    Returns:
        ``(low, high)``, the ``(1 - level)/2`` and ``(1 + level)/2`` percentiles of the mean
        over ``draws`` resamples of as many groups as there are, with replacement.
    """
    values = np.asarray(values, float)
    if values.ndim != 1 or values.shape != np.shape(groups) or len(values) == 0:
        raise ValueError(f"values and groups: one value per sample, same length; got "
                         f"{values.shape} and {np.shape(groups)}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1); got {level}")
    _, index = np.unique(groups, return_inverse=True)
    sums = np.bincount(index, values)
    counts = np.bincount(index).astype(float)
    pick = np.random.default_rng(seed).integers(0, len(sums), (draws, len(sums)))
    means = sums[pick].sum(1) / counts[pick].sum(1)
    low, high = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


MIN_GROUPS_SHOWN = 5
"""Groups in which a share's rarer outcome (a miss of a 95 % interval) must show before its
clustering is read from them (:func:`effective_count`); in fewer, the answers are worth their
groups."""


def effective_count(hit, groups) -> float:
    """How many independent answers ``hit`` ``(n,)`` (1: covered, 0: not) are worth when they
    come in ``groups`` ``(n,)`` (labels) that share their errors, as the windows of one
    specimen do: ``n`` over the design effect, ``p (1 - p) / var``, with ``var`` the
    cluster-robust variance of the share ``p`` (the groups' summed deviations ``Σ_i (h_i -
    p)``, squared and summed, times ``G / (G - 1) / n²``), at most ``n`` (never narrower than
    the binomial). Where the rarer outcome shows in fewer than :data:`MIN_GROUPS_SHOWN` of the
    ``G`` groups (every answer alike, or a 95 % interval's few misses), its clustering cannot
    be read, and the answers are worth their groups, ``n² / Σ_g n_g²`` (``G`` for groups of
    one size; fewer where some are larger): the cautious end, since a group's answers may all
    fail together (192 of 192 windows of 48 specimens are judged as 48 groups, and so are 191
    of 192). With one group, 1.

    Raises:
        ValueError: ``groups`` missing or of another length, or ``hit`` not finite.
    """
    hit = np.asarray(hit, float)
    if groups is None or hit.ndim != 1 or np.shape(groups) != hit.shape:
        raise ValueError(f"hit and groups: one label per answer, both (n,); got {hit.shape} "
                         f"and {None if groups is None else np.shape(groups)}")
    if not np.isfinite(hit).all():
        raise ValueError("hit: every answer 0 or 1; leave out rows without one (NaN) first")
    n = len(hit)
    _, which = np.unique(np.asarray(groups), return_inverse=True)
    sizes = np.bincount(which).astype(float)
    if len(sizes) < 2:
        return float(min(n, 1))
    g = len(sizes)
    p = float(hit.mean())
    rare = hit if p < 0.5 else 1.0 - hit
    if np.count_nonzero(np.bincount(which, rare)) < MIN_GROUPS_SHOWN:
        return float(n * n / np.sum(sizes**2))
    var = g / (g - 1) * float(np.sum(np.bincount(which, hit - p) ** 2)) / n**2
    return float(n) if var <= 0 else float(min(n, p * (1 - p) / var))


def statistic_interval(values, statistic, *, level: float = 0.95, draws: int = 1000,
                       seed: int = 0) -> tuple[float, float]:
    """Percentile-bootstrap interval of ``statistic(values)`` over independent samples.

    Args:
        values: per sample, ``(n,)`` (e.g. absolute errors).
        statistic: ``(draws, n) -> (draws,)`` along the last axis (``lambda x: np.median(x,
            -1)``; an RMS: ``lambda x: np.sqrt(np.mean(x**2, -1))``).
        level: the interval's coverage, in (0, 1).
        draws: bootstrap resamples (in chunks, so memory stays ~ 64 MB).

    Returns:
        ``(low, high)``.
    """
    values = np.asarray(values, float)
    if values.ndim != 1 or len(values) == 0:
        raise ValueError(f"values: one per sample, at least one; got shape {values.shape}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1); got {level}")
    rng = np.random.default_rng(seed)
    chunk = max(1, 8_000_000 // len(values))
    stats = np.concatenate([statistic(values[rng.integers(0, len(values), (k, len(values)))])
                            for k in np.diff(np.r_[0:draws:chunk, draws])])
    low, high = np.quantile(stats, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


def span(interval, signed: bool = False) -> str:
    """``(low, high)`` fractions as percentages (points where ``signed``)."""
    low, high = (100 * x for x in interval)
    return f"{low:+.1f} to {high:+.1f}" if signed else f"{low:.1f}–{high:.1f} %"
