"""Honest uncertainty after training (issue 25 §4): each decoder's intervals and class
probabilities recalibrated on held-out data it did not train on, the parameters inside its
exported graph.

Two well-kept methods:

- **σ and a 95 % width per range of the answer** (split conformal, Mondrian by range): the
  decoder's own σ (or, for a decoder without one, a unit σ) times a scale per range of its
  answer, and the half-width of its 95 % interval in those σ, both fitted on held-out records
  so that ±1σ covers 68.27 % and ±width·σ 95 % of them in every range (:func:`fit_scales`):
  the split-conformal quantiles ``q68(|err|/σ)`` and ``q95(|err|/σ)``. Per range, because a
  decoder's errors change over its range (fluid: η's relative error falls tenfold over its
  decades), and a single scale would cover too much at one end and too little at the other;
  by the answer, because the truth is what a device does not know. Per level, because the
  errors are not Gaussian: fluid ρ's are lighter-tailed (``q95/q68`` 1.6–1.7, a Gaussian's
  1.96), texture's grain heavier, so that one σ cannot hold both levels (the width is 1.96
  for Gaussian errors).
- **and per class of the truth** (split conformal, Mondrian by label; Vovk et al., 2005,
  "label-conditional"), for a value that is one per class of a classifier (texture's grain,
  one mean size per grade): an interval per range of the answer cannot cover a class that
  the classifier takes for its neighbour (the texture decoder named P280's windows P320
  18–23 % of the time, and those answers fell in P320's range: P280 covered 60–62 % at ±1σ
  on 1200 specimens in every row and draw, P1200 74 %). So each interval also reaches every
  class whose recalibrated probability is at or above that class's threshold
  (:func:`class_thresholds`: the conformal quantile of ``1 - p_true`` over that class's
  held-out windows that σ alone misses), and σ's part is first scaled so that no class is
  covered above the level by σ alone (:func:`class_intervals`).
- **temperature scaling** (Guo et al., 2017): class probabilities ``softmax(log p / T)``, one
  ``T`` fitted by the negative log-likelihood of held-out windows (:func:`fit_temperature`); it
  never changes the likeliest class. Then **top-label Platt scaling** (Platt, 1999, on the
  top label as in Gupta & Ramdas, 2022): the likeliest class's probability ``t`` becomes
  ``sigmoid(a·logit t + b)`` and the others share the rest in their proportions, ``a`` and
  ``b`` fitted by the likelihood of the top answer being right (:func:`fit_top_label`); it
  never lowers the top class below the second (:data:`KEEP`), so it too keeps the likeliest
  class. One ``T`` trades every confidence alike; the texture decoder's windows of 0.7–0.9
  confidence were right 3–5 points less often than stated while those above 0.97 were not,
  a shape that the map's bias takes (on held-out LuGre friction, fitted in family only: ECE
  2.7 → 1.8 % on 1200 specimens, 29 Nov).

:class:`Recalibrated` wraps an exported net and applies the scales and the temperature in its
graph (a few comparisons, a sum and a product per σ; a log, a division, a softmax and the
top label's map for the probabilities), so that every graph of the export and ``wtml
predict`` give the recalibrated values. The metadata states what was fitted, on what, and
how much it moved the coverage (:class:`wtml.runtime.metadata.Uncertainty`), and holds
the 95 % widths, which the device runtime applies
(:meth:`wtml.runtime.metadata.IntervalRecalibration.half_width`: ``wtml predict``'s
``<σ>_95`` columns); a graph's σ output is the 68 % half-width.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import torch
from torch import nn
from torch.nn import functional as fn

from wtml.runtime.metadata import (
    CLASS_FLOOR,
    CLASS_MARGIN,
    NEVER,
    WIDE,
    IntervalRecalibration,
    Uncertainty,
    class_distance,
    class_reach,
)
from wtml.schema import to_dict

NOMINAL = (0.6827, 0.95)
"""The coverage of ±1σ and of ±1.96σ (:data:`~wtml.runtime.metadata.WIDE`) for a Gaussian
error: the levels of the two intervals."""
MAX_WIDTH = 1e6
"""The largest 95 % width in σ: where most held-out errors vanish (q68 of 0), σ's scale is
raised to q95 / MAX_WIDTH rather than left at 0."""
TINY = 1e-30
"""Probabilities are floored here before their log (a float32 softmax underflows to 0)."""
MIN_PER_RANGE = 40
"""Held-out answers per range, at least: a coverage of 68 % measured on fewer is ±7 points."""
ECE_BINS = 15
"""Equal-width confidence bins of the expected calibration error."""


def in_widths(err: np.ndarray, half: np.ndarray) -> np.ndarray:
    """``|err| / half`` ``(n,)``, 0 where both are 0 (an exact answer is inside any interval)
    and inf where only ``half`` is."""
    err = np.abs(err)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return np.where(err == 0, 0.0, np.where(half > 0, err / half, np.inf))


def coverage(err: np.ndarray, sigma: np.ndarray, wide: float | np.ndarray = WIDE
             ) -> tuple[float, float]:
    """The shares of ``|err| <= 1σ`` and ``|err| <= wide·σ`` over the rows where both are
    finite (NaN where none is), ``err`` and ``sigma`` ``(n,)`` in one unit, ``wide`` the 95 %
    half-width in σ (one, or ``(n,)`` per row)."""
    err, sigma = np.asarray(err, float), np.asarray(sigma, float)
    wide = np.broadcast_to(np.asarray(wide, float), err.shape)
    ok = np.isfinite(err) & np.isfinite(sigma)
    if not ok.any():
        return float("nan"), float("nan")
    z = in_widths(err[ok], sigma[ok])
    return float(np.mean(z <= 1.0)), float(np.mean(z <= wide[ok]))


def conformal_quantile(z: np.ndarray, level: float) -> float:
    """The split-conformal quantile of scores ``z`` ``(n,)`` (not NaN, n >= 1): the
    ⌈(n + 1)·level⌉-th smallest (the largest where that exceeds n), so that a fresh score
    exchangeable with them lies at or below it with probability >= ``level``."""
    z = np.sort(np.asarray(z, float))
    return float(z[min(len(z), int(np.ceil((len(z) + 1) * level))) - 1])


def level_widths(z: np.ndarray) -> tuple[float, float]:
    """The scale on σ and the 95 % half-width in scaled σ from ``z = |err|/σ`` ``(n,)``
    (>= 0, inf allowed, n >= 1): ``q68(z)`` and ``q95(z) / q68(z)`` (:func:`conformal_quantile`), so
    that ``|err| <= scale·σ`` holds for 68.27 % of them and ``|err| <= width·scale·σ`` for
    95 % (the width rounded up by a float step, so that the product does not round below
    q95). Both stay what the metadata allows: the width in [1, :data:`MAX_WIDTH`], a q68 of 0
    (errors that mostly vanish) raising the scale to ``q95 / MAX_WIDTH``; the scale in
    [:data:`TINY`, 1 / TINY] (a σ that underflows makes ``z`` infinite)."""
    q68, q95 = (conformal_quantile(z, level) for level in NOMINAL)
    scale = float(np.clip(max(q68, q95 / MAX_WIDTH), TINY, 1 / TINY))
    return scale, float(np.clip(np.nextafter(q95 / scale, np.inf), 1.0, MAX_WIDTH))


def fit_scales(err: np.ndarray, sigma: np.ndarray, by: np.ndarray, n_ranges: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scales on σ and 95 % widths per range of ``by`` (:func:`level_widths` in each).

    Args:
        err: the errors ``(n,)`` in σ's unit (estimate − truth; of ln values for a σ of ln).
        sigma: the decoder's σ ``(n,)`` (ones for a decoder without one); rows where it or
            ``err`` is not finite (out of domain, no answer) are left out.
        by: what picks the range, ``(n,)``: the decoder's own answer.
        n_ranges: ranges of equal count (quantiles of ``by``); fewer where the rows are too
            few for :data:`MIN_PER_RANGE` each.

    Returns:
        ``edges`` ``(K-1,)`` ascending, in ``by``'s unit, ``scales`` ``(K,)`` and ``widths``
        ``(K,)``: range k is ``edges[k-1] <= by < edges[k]`` (open at both ends), where the
        68 % interval is ±scales[k]·σ and the 95 % interval ±widths[k]·scales[k]·σ. Fewer
        than :data:`MIN_PER_RANGE` usable rows (a decoder that flags nearly all of them out of
        domain) leave σ as it is: one range, scale 1, the Gaussian width 1.96 (the metadata
        states how many rows).
    """
    err, sigma, by = (np.asarray(x, float) for x in (err, sigma, by))
    ok = np.isfinite(err) & np.isfinite(sigma) & np.isfinite(by) & (sigma > 0)
    if ok.sum() < MIN_PER_RANGE:
        return np.zeros(0), np.ones(1), np.full(1, WIDE)
    with np.errstate(over="ignore"):
        z, by = np.abs(err[ok]) / sigma[ok], by[ok]
    k = int(max(1, min(n_ranges, len(z) // MIN_PER_RANGE)))
    edges = np.unique(np.quantile(by, np.arange(1, k) / k)) if k > 1 else np.zeros(0)
    which = np.searchsorted(edges, by, side="right")
    scales, widths = np.array([level_widths(z[which == j]) if np.any(which == j)
                               else (1.0, WIDE) for j in range(len(edges) + 1)]).T
    return edges, scales, widths


def class_thresholds(err: np.ndarray, base: np.ndarray, probabilities: np.ndarray,
                     labels: np.ndarray, class_values, log_value: bool, level: float,
                     value: np.ndarray, rounds: int = 10) -> np.ndarray:
    """Per class the least probability ``τ_k`` at which an interval reaches class k
    (:func:`~wtml.runtime.metadata.class_reach`) so that the intervals ``max(base, reach)``
    cover at least ``level`` of the held-out answers of each class: the split-conformal
    quantile (:func:`conformal_quantile`) of the score ``1 - p_k`` over class k's answers,
    0 for those covered already by ``base`` or by the other classes' reach; :data:`NEVER`
    where ``base`` covers enough (or the class has fewer than :data:`MIN_PER_RANGE`
    answers). A class's reach can cover another's answers, so the classes are fitted in turn,
    round after round (each from the last) until a round changes none, at most ``rounds``.

    Args:
        err, base: the errors and the half-widths without the classes, ``(n,)``, in σ's
            unit (finite: the answers in domain).
        probabilities: the recalibrated class probabilities ``(n, C)``.
        labels: the true classes ``(n,)`` (ints in [0, C)).
        class_values, log_value: as :func:`~wtml.runtime.metadata.class_reach`'s.
        level: the interval's coverage per class.
        value: the answers ``(n,)``.
    """
    n_classes = probabilities.shape[1]
    distance = class_distance(value, class_values, log_value).astype(float)
    tau = np.full(n_classes, NEVER)
    for _ in range(rounds):
        before = tau.copy()
        for k in range(n_classes):
            mine = labels == k
            if mine.sum() < MIN_PER_RANGE:
                continue
            others = np.where(np.arange(n_classes) == k, NEVER, tau)
            reach = np.max(np.where(probabilities[mine] >= others, distance[mine], 0.0), 1)
            covered = np.abs(err[mine]) <= np.maximum(base[mine], reach)
            p_true = np.nan_to_num(probabilities[mine, k], nan=0.0)  # NaN reaches nothing
            q = conformal_quantile(np.where(covered, 0.0, 1.0 - p_true), level)
            tau[k] = NEVER if q <= 0 else 1.0 - q
        if np.array_equal(tau, before):
            break
    return tau


def class_intervals(err: np.ndarray, sigma: np.ndarray, which: np.ndarray, scales: np.ndarray,
                    widths: np.ndarray, probabilities: np.ndarray, labels: np.ndarray,
                    class_values, log_value: bool, value: np.ndarray) -> dict:
    """The per-range scales and widths (:func:`fit_scales`'s, ``(K,)``) made to leave room
    for the classes, and the classes' thresholds at both levels (:func:`class_thresholds`),
    from held-out answers in domain (``err``, ``sigma``, their ranges ``which``, the
    recalibrated ``probabilities`` ``(n, C)``, ``labels``, ``value``, each ``(n,)`` but the
    probabilities). First σ's scale is multiplied by the least over the classes of the
    conformal 68 % quantile of ``|err| / (scale·σ)`` in that class, so that σ alone covers
    no class above 68 % (a range's scale fitted over all its answers covered the finest
    grade 70–74 %), and the 68 % thresholds fill each class up to its level; then the same
    for the 95 % widths about the 68 % intervals (never below 1). Returns ``scales``,
    ``widths``, ``thresholds``, ``thresholds_wide``."""
    present = [k for k in range(probabilities.shape[1]) if np.sum(labels == k) >= MIN_PER_RANGE]
    if not present:
        n = probabilities.shape[1]
        return {"scales": scales, "widths": widths, "thresholds": np.full(n, NEVER),
                "thresholds_wide": np.full(n, NEVER)}

    def least(base: np.ndarray, level: float) -> float:
        """The least over the classes of the conformal quantile of ``|err| / base``."""
        return min(conformal_quantile(in_widths(err[labels == k], base[labels == k]), level)
                   for k in present)

    fit = {}
    shrink = least(scales[which] * sigma, NOMINAL[0])
    fit["scales"] = np.clip(scales * shrink, TINY, 1 / TINY)
    base = fit["scales"][which] * sigma
    args = (probabilities, labels, class_values, log_value)
    fit["thresholds"] = class_thresholds(err, base, *args, NOMINAL[0], value)
    r68 = np.maximum(base, class_reach(value, probabilities, class_values, fit["thresholds"],
                                       log_value))
    shrink = least(widths[which] * r68, NOMINAL[1])
    fit["widths"] = np.clip(np.nextafter(widths * shrink, np.inf), 1.0, MAX_WIDTH)
    fit["thresholds_wide"] = class_thresholds(err, fit["widths"][which] * r68, *args,
                                              NOMINAL[1], value)
    return fit


def fit_temperature(probabilities: np.ndarray, labels: np.ndarray) -> float:
    """The temperature ``T`` minimising the negative log-likelihood of ``labels`` ``(n,)``
    (class indices) under ``softmax(log p / T)``, ``probabilities`` ``(n, C)``; searched in
    log T over [1e-2, 1e2] (a bounded scalar minimisation)."""
    from scipy.optimize import minimize_scalar

    logp = np.log(np.clip(np.asarray(probabilities, float), TINY, 1.0))
    labels = np.asarray(labels, int)

    def nll(log_t: float) -> float:
        x = logp / np.exp(log_t)
        x = x - x.max(1, keepdims=True)
        return float(np.mean(np.log(np.exp(x).sum(1)) - x[np.arange(len(x)), labels]))

    return float(np.exp(minimize_scalar(nll, bounds=(np.log(1e-2), np.log(1e2)),
                                        method="bounded").x))


TOP_MIN = 10
"""Right and wrong top answers each, at least, to fit :func:`fit_top_label` (with fewer, a
logistic fit runs off to an infinite slope): the identity (slope 1, bias 0) otherwise."""
EXCLUDE = 1e4
"""Subtracted from the top class's log probability to leave it out of the others' log sum
(finite, unlike -inf, so no NaN in float32; after ``TINY`` and a temperature T the others'
are above ln(TINY)/T, -6908 at the fit's least T of 0.01)."""


KEEP = 1e-4
"""The least the mapped top label's logit stays above what would tie it with the second
class (:func:`top_label`): the map never changes the likeliest class."""


def _softplus(x: np.ndarray) -> np.ndarray:
    return np.logaddexp(0.0, x)


def _top_parts(probabilities: np.ndarray) -> tuple[np.ndarray, ...]:
    """Of probabilities ``(n, C)``: their normalised logs ``(n, C)``, the top class's mask
    ``(n, C)`` (one class: the first of a tie, as argmax), the top log, the log of the
    others' sum and the second class's log, each ``(n, 1)``, float64, as
    :class:`Recalibrated`'s graph computes them (a tie is then a second class as likely,
    which the :data:`KEEP` floor sets just below the top: the map is continuous there)."""
    lp = np.log(np.clip(np.asarray(probabilities, float), TINY, 1.0))
    lp = lp - np.logaddexp.reduce(lp, -1, keepdims=True)
    is_top = np.arange(lp.shape[-1]) == lp.argmax(-1)[..., None]
    top = lp.max(-1, keepdims=True)
    others = lp - EXCLUDE * is_top
    rest = np.logaddexp.reduce(others, -1, keepdims=True)
    return lp, is_top, top, rest, others.max(-1, keepdims=True)


def top_label(probabilities: np.ndarray, slope: float, bias: float) -> np.ndarray:
    """Top-label Platt scaling of ``probabilities`` ``(n, C)``, float64 (what the graph
    does): the likeliest class's ``t`` becomes ``sigmoid(slope·logit t + bias)``, but never
    less than keeps it the likeliest (:data:`KEEP`), and the others share ``1 -`` that in
    their proportions; renormalised."""
    lp, is_top, top, rest, second = _top_parts(probabilities)
    s = np.maximum(slope * (top - rest) + bias, second - rest + KEEP)
    out = np.exp(np.where(is_top, -_softplus(-s), lp - rest - _softplus(s)))
    return out / out.sum(-1, keepdims=True)


def fit_top_label(probabilities: np.ndarray, labels: np.ndarray) -> tuple[float, float]:
    """``(slope, bias)`` of :func:`top_label` maximising the likelihood that each window's
    top answer is right (a logistic regression on ``logit t``), for probabilities ``(n, C)``
    already tempered and ``labels`` ``(n,)``; the identity ``(1, 0)`` where fewer than
    :data:`TOP_MIN` answers are right or wrong, or the fit is not increasing."""
    from scipy.optimize import minimize

    _, is_top, top, rest, _ = _top_parts(probabilities)
    logit = (top - rest)[:, 0]
    labels = np.asarray(labels)
    sign = np.where(is_top[np.arange(len(labels)), labels], 1.0, -1.0)
    ok = np.isfinite(logit)  # a row of NaN probabilities tells nothing
    logit, sign = logit[ok], sign[ok]
    if min(np.sum(sign > 0), np.sum(sign < 0)) < TOP_MIN:
        return 1.0, 0.0

    def loss(ab: np.ndarray) -> tuple[float, np.ndarray]:
        m = sign * (ab[0] * logit + ab[1])
        g = -sign / (1 + np.exp(np.clip(m, -700, 700)))  # d softplus(-m) / d (a l + b)
        return float(np.mean(_softplus(-m))), np.array([np.mean(g * logit), np.mean(g)])

    slope, bias = minimize(loss, np.array([1.0, 0.0]), jac=True, method="BFGS").x
    if not (1e-3 <= slope <= 1e3 and abs(bias) <= 1e3):
        return 1.0, 0.0
    return float(slope), float(bias)


def recalibrated(probabilities: np.ndarray, uncertainty: Uncertainty) -> np.ndarray:
    """``probabilities`` ``(n, C)`` as the recalibrated graph gives them, float64: tempered,
    then top-label scaled (an export made before the top label's map: tempered only)."""
    p = tempered(probabilities, uncertainty.temperature)
    if uncertainty.top_slope is None:
        return p
    return top_label(p, uncertainty.top_slope, uncertainty.top_bias)


def expected_calibration_error(probabilities: np.ndarray, labels: np.ndarray,
                               bins: int = ECE_BINS) -> tuple[float, dict[str, np.ndarray]]:
    """The expected calibration error of a classifier's ``probabilities`` ``(n, C)`` on
    ``labels`` ``(n,)``: the count-weighted mean of ``|accuracy − confidence|`` over
    ``bins`` equal-width bins of the confidence (the top probability), and its reliability
    curve: per bin ``confidence`` (mean), ``accuracy`` and ``count``, each ``(bins,)`` (NaN
    in an empty bin)."""
    p = np.asarray(probabilities, float)
    return binned_calibration(p.max(1), p.argmax(1) == np.asarray(labels), bins)


def binned_calibration(confidence: np.ndarray, hit: np.ndarray, bins: int = ECE_BINS
                       ) -> tuple[float, dict[str, np.ndarray]]:
    """:func:`expected_calibration_error` of answers given as their ``confidence`` (the top
    probability, ``(n,)``) and whether each was right (``hit``, ``(n,)`` bool)."""
    conf, hit = np.asarray(confidence, float), np.asarray(hit, float)
    which = np.clip(np.ceil(conf * bins).astype(int) - 1, 0, bins - 1)
    count = np.bincount(which, minlength=bins).astype(float)
    with np.errstate(invalid="ignore"):
        mean_conf = np.bincount(which, conf, bins) / count
        accuracy = np.bincount(which, hit, bins) / count
    ece = float(np.nansum(count * np.abs(accuracy - mean_conf)) / max(len(conf), 1))
    return ece, {"confidence": mean_conf, "accuracy": accuracy, "count": count}


def tempered(probabilities: np.ndarray, temperature: float) -> np.ndarray:
    """``softmax(log p / T)`` of ``probabilities`` ``(n, C)``, float64 (what the graph does)."""
    x = np.log(np.clip(np.asarray(probabilities, float), TINY, 1.0)) / temperature
    x = np.exp(x - x.max(-1, keepdims=True))
    return x / x.sum(-1, keepdims=True)


def interval(spec: dict, outputs: dict[str, np.ndarray], truth: np.ndarray, n_ranges: int,
             classes: tuple[np.ndarray, np.ndarray] | None = None) -> IntervalRecalibration:
    """Fit one σ output's recalibration on held-out answers.

    Args:
        spec: ``sigma``, ``value``, ``by`` (output names), ``log_value`` (σ is of ln value)
            and ``stored`` (``"std"``, ``"log_std"`` or ``"none"``: how the net gives σ), as
            :class:`~wtml.runtime.metadata.IntervalRecalibration` has them; for a value of
            one value per class, ``classes`` (the probabilities' output) and
            ``class_values``.
        outputs: the graph's answers by name before recalibration, each ``(n,)``, its domain
            gate's already applied (σ NaN out of domain).
        truth: the true values of ``spec["value"]``, ``(n,)`` (NaN: nothing to answer).
        n_ranges: ranges of the answer (:func:`fit_scales`).
        classes: with ``spec["classes"]``, the recalibrated probabilities ``(n, C)`` (as the
            graph gives them) and the true classes ``(n,)`` (:func:`class_intervals`).

    Raises:
        ValueError: ``spec["classes"]`` without ``classes``.
    """
    err = errors(outputs[spec["value"]], truth, spec["log_value"])
    sigma = raw_sigma(spec, outputs, len(err))
    edges, scales, widths = fit_scales(err, sigma, outputs[spec["by"]], n_ranges)
    used = np.isfinite(err) & np.isfinite(sigma)
    before = () if spec["stored"] == "none" or not used.any() else coverage(err, sigma)
    fitted = IntervalRecalibration(**spec, edges=tuple(map(float, edges)),
                                   scales=tuple(map(float, scales)),
                                   widths=tuple(map(float, widths)), n=int(used.sum()),
                                   coverage_before=before)
    if spec.get("classes"):
        if classes is None:
            raise ValueError(f"interval {spec['sigma']!r}: its classes {spec['classes']!r} "
                             f"need the probabilities and the true classes")
        fitted = dataclasses.replace(fitted, thresholds=(NEVER,) * len(spec["class_values"]),
                                     thresholds_wide=(NEVER,) * len(spec["class_values"]))
    if not used.any():
        return fitted
    which = fitted.range_of(outputs[spec["by"]])  # as the graph and the runtime find it
    if spec.get("classes"):
        p, labels = (np.asarray(x)[used] for x in classes)
        value = np.asarray(outputs[spec["value"]])[used]
        fit = class_intervals(err[used], sigma[used], which[used], scales, widths, p,
                              labels.astype(int), spec["class_values"], spec["log_value"],
                              value)
        fitted = dataclasses.replace(fitted, **{k: tuple(map(float, v)) for k, v in fit.items()})
        r68 = np.maximum(np.asarray(fitted.scales)[which[used]] * sigma[used], class_reach(
            value, p, fitted.class_values, fitted.thresholds, fitted.log_value))
        log_std = spec["stored"] == "log_std"
        with np.errstate(divide="ignore"):  # a σ of 0 (no reach, no σ): its log is -inf
            shown = np.log(r68) if log_std else r68  # the σ output as the graph gives it
        half = fitted.half_width(shown, np.asarray(outputs[spec["by"]])[used],
                                 {spec["value"]: value, spec["classes"]: p,
                                  spec["sigma"]: shown})
        r95 = np.exp(half) if log_std else half  # as the runtime reads the graph's answer
        inside = np.abs(err[used])
        return dataclasses.replace(fitted, coverage_after=(
            float(np.mean(inside <= r68)), float(np.mean(inside <= r95))))
    return dataclasses.replace(fitted, coverage_after=coverage(
        err, sigma * scales[which], widths[which]))


def fit_uncertainty(outputs: dict[str, np.ndarray], truth: dict[str, np.ndarray],
                    specs: list[dict], n_ranges: int, fitted_on: str,
                    probabilities: str | None = None,
                    labels: np.ndarray | None = None) -> Uncertainty:
    """Every recalibration of one decoder from its answers on held-out data.

    Args:
        outputs: the gated graph's answers by output name before recalibration (``(n,)``;
            probabilities ``(n, C)``).
        truth: the true value of each spec's ``value``, ``(n,)``.
        specs: one per σ output (:func:`interval`).
        n_ranges: ranges of the answer per σ (:func:`fit_scales`).
        fitted_on: what the data were (stated in the metadata).
        probabilities, labels: a classifier's probabilities output and the true classes
            ``(n,)``: a temperature is fitted (:func:`fit_temperature`), then the top
            label's map on the tempered probabilities (:func:`fit_top_label`), first: a
            spec with ``classes`` (that output) is fitted on the recalibrated probabilities.
            Rows whose probabilities are not finite are left out of every fit.
    """
    if probabilities is None:
        return Uncertainty(fitted_on=fitted_on, intervals=tuple(
            interval(s, outputs, truth[s["value"]], n_ranges) for s in specs))
    # a window with NaN probabilities (NaN inputs, which the gate flags) tells the fit nothing
    answered = np.isfinite(np.asarray(outputs[probabilities], float)).all(1)
    if not answered.any():
        raise ValueError(f"fit_uncertainty: none of the {len(answered)} rows of "
                         f"{probabilities!r} is finite: nothing to fit a classifier's "
                         "recalibration on")
    outputs = {k: np.asarray(v)[answered] for k, v in outputs.items()}
    truth = {s["value"]: np.asarray(truth[s["value"]])[answered] for s in specs}
    labels = np.asarray(labels)[answered]
    p = np.asarray(outputs[probabilities], float)
    temperature = fit_temperature(p, labels)
    slope, bias = fit_top_label(tempered(p, temperature), labels)
    if (slope, bias) == (1.0, 0.0):  # nothing fitted: no map (the floor would still move ties)
        slope = bias = None
    fitted = Uncertainty(fitted_on=fitted_on, probabilities=probabilities,
                         temperature=temperature, top_slope=slope, top_bias=bias,
                         ece_before=expected_calibration_error(p, labels)[0])
    after = recalibrated(p, fitted)
    intervals = tuple(interval(s, outputs, truth[s["value"]], n_ranges,
                               (after, labels) if s.get("classes") == probabilities else None)
                      for s in specs)
    return dataclasses.replace(fitted, intervals=intervals,
                               ece_after=expected_calibration_error(after, labels)[0])


def metadata(uncertainty: Uncertainty) -> str:
    """The metadata's ``uncertainty`` value (JSON)."""
    return json.dumps(to_dict(uncertainty))


def errors(estimate: np.ndarray, truth: np.ndarray, log_value: bool) -> np.ndarray:
    """estimate − truth, of ln values where ``log_value`` (NaN where either is missing or,
    for ln, not positive)."""
    estimate, truth = np.asarray(estimate, float), np.asarray(truth, float)
    if not log_value:
        return estimate - truth
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((estimate > 0) & (truth > 0), np.log(estimate) - np.log(truth), np.nan)


def raw_sigma(spec: dict, outputs: dict[str, np.ndarray], n: int) -> np.ndarray:
    """The decoder's own σ in the value's unit (of ln value where ``log_value``) as ``spec``
    says it stores it: the output, its exp (``"log_std"``), or ones (``"none"``)."""
    if spec["stored"] == "none":
        return np.ones(n)
    sigma = np.asarray(outputs[spec["sigma"]], float)
    return np.exp(sigma) if spec["stored"] == "log_std" else sigma


class Recalibrated(nn.Module):
    """A net with its recalibration in the graph: ``(*inputs) -> outputs`` with each σ of
    ``uncertainty.intervals`` scaled per range of its ``by`` output (a decoder without σ gets
    one appended, after the net's outputs, in the order of the intervals) and the
    ``probabilities`` output tempered and top-label scaled.

    Where the net answers from features (``from_features``) and shares its feature layer
    (``features``) with a domain gate, so does this: :class:`~wtml.decoders.domain.Gated`
    around it still computes the features once.

    Args:
        net: the exported net, returning a tuple of ``(batch, ...)`` tensors.
        names: the net's outputs' names, in order.
        uncertainty: what to apply (:func:`interval`, :func:`fit_temperature`,
            :func:`fit_top_label`).
    """

    def __init__(self, net: nn.Module, names: tuple[str, ...], uncertainty: Uncertainty
                 ) -> None:
        super().__init__()
        self.net, self.names = net, tuple(names)
        added = [r.sigma for r in uncertainty.intervals if r.sigma not in self.names]
        self.outputs = self.names + tuple(added)
        """The graph's outputs' names: the net's, then the σ appended."""
        self.rules, self.reaches = [], {}
        """Per interval (output index of σ, of ``by``, how σ is stored); per interval with
        classes (by its index) the output index of its value, of its probabilities, and
        whether σ is of ln value."""
        for k, r in enumerate(uncertainty.intervals):
            self.register_buffer(f"edges_{k}", torch.tensor(r.edges, dtype=torch.float32))
            # the scale of range j is scales[0] + Σ_{i<j} steps[i]
            steps = np.diff(r.scales) if r.stored != "log_std" else np.diff(np.log(r.scales))
            first = r.scales[0] if r.stored != "log_std" else np.log(r.scales[0])
            self.register_buffer(f"steps_{k}", torch.tensor(steps, dtype=torch.float32))
            self.register_buffer(f"first_{k}", torch.tensor(float(first)))
            self.rules.append((self.outputs.index(r.sigma), self.names.index(r.by), r.stored))
            if r.classes:  # f(v_k) as class_distance computes it: float32, then its log
                values = torch.tensor(r.class_values, dtype=torch.float32)
                self.register_buffer(f"classes_{k}", torch.log(values) if r.log_value
                                     else values)
                self.register_buffer(f"thresholds_{k}",
                                     torch.tensor(r.thresholds, dtype=torch.float32))
                self.reaches[k] = (self.names.index(r.value), self.names.index(r.classes),
                                   r.log_value)
        self.tempered, self.top_label = None, False
        if uncertainty.temperature is not None:
            self.tempered = self.names.index(uncertainty.probabilities)
            self.register_buffer("temperature", torch.tensor(float(uncertainty.temperature)))
        if uncertainty.top_slope is not None:
            self.top_label = True
            self.register_buffer("top_slope", torch.tensor(float(uncertainty.top_slope)))
            self.register_buffer("top_bias", torch.tensor(float(uncertainty.top_bias)))

    @property
    def features(self) -> nn.Module:
        """The net's feature layer (shared with the domain gate where the net has one)."""
        return self.net.features

    def from_features(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The recalibrated outputs from features already computed."""
        return self.recalibrate(tuple(self.net.from_features(x)))

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return self.recalibrate(tuple(self.net(*inputs)))

    def recalibrate(self, outputs: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
        """The net's outputs -> the graph's (:attr:`outputs`): the probabilities first (an
        interval with classes reaches by the recalibrated ones), then each σ."""
        out = list(outputs)
        if self.tempered is not None:
            p = out[self.tempered]
            lp = torch.log_softmax(torch.log(p.clamp_min(TINY)) / self.temperature, -1)
            out[self.tempered] = self.top_mapped(lp) if self.top_label else torch.exp(lp)
        for k, (at, by, stored) in enumerate(self.rules):
            edges, steps = getattr(self, f"edges_{k}"), getattr(self, f"steps_{k}")
            first = getattr(self, f"first_{k}")
            if len(edges):  # a NaN answer compares false everywhere: the first range
                # Mul and ReduceSum: onnxruntime's MatMul by a vector took 5x as long
                above = (out[by][:, None] >= edges).to(first.dtype)
                scale = (above * steps).sum(-1) + first
            else:
                scale = first.expand_as(out[by])
            if stored == "none":
                if at < len(out):
                    out[at] = scale
                else:
                    out.append(scale)
            elif stored == "log_std":
                out[at] = out[at] + scale
            else:
                out[at] = out[at] * scale
            if k in self.reaches:
                reach = self.class_reach(k, out)
                out[at] = torch.maximum(out[at], torch.log(reach.clamp_min(TINY))
                                        if stored == "log_std" else reach)
        return tuple(out)

    def class_reach(self, k: int, out: list[torch.Tensor]) -> torch.Tensor:
        """Interval k's reach ``(batch,)`` over the graph's outputs ``out`` (the probabilities
        recalibrated): :func:`~wtml.runtime.metadata.class_reach`, whose float64 twin this
        is."""
        value_at, classes_at, log_value = self.reaches[k]
        value = out[value_at]
        if log_value:
            value = torch.log(value.clamp_min(TINY))
        values = getattr(self, f"classes_{k}")
        distance = ((value[:, None] - values).abs() * (1 + CLASS_MARGIN)
                    + CLASS_FLOOR * torch.maximum(value[:, None].abs(), values.abs()))
        likely = out[classes_at] >= getattr(self, f"thresholds_{k}")
        return torch.where(likely, distance, torch.zeros_like(distance)).amax(-1)

    def top_mapped(self, lp: torch.Tensor) -> torch.Tensor:
        """Tempered log probabilities ``(batch, C)`` -> probabilities with the top label's
        map (:func:`top_label`, whose float64 twin this is)."""
        top = lp.amax(-1, keepdim=True)
        classes = torch.arange(lp.shape[-1], device=lp.device)
        is_top = (classes == lp.argmax(-1, keepdim=True)).to(lp.dtype)  # the first of a tie
        others = lp - EXCLUDE * is_top
        rest = torch.logsumexp(others, -1, keepdim=True)
        s = torch.maximum(self.top_slope * (top - rest) + self.top_bias,
                          others.amax(-1, keepdim=True) - rest + KEEP)
        mapped = torch.exp(is_top * -fn.softplus(-s) + (1 - is_top) * (lp - rest - fn.softplus(s)))
        return mapped / mapped.sum(-1, keepdim=True)
