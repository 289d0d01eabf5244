"""Intervals per class of the truth (issue 25 §4): a value that is one per class of a
classifier (texture's grain, one size per grade) whose classifier takes one class for its
neighbour. A scale per range of the answer cannot cover that class; reaching every class as
likely as its threshold does, at both levels, in the graph (torch and ONNX) as the metadata
and the device runtime state it."""

from __future__ import annotations

import json
import warnings

import numpy as np
import onnxruntime as ort
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

from wtml.decoders.domain import DomainGate, Gated, ZeParts
from wtml.decoders.recalibration import (
    MIN_PER_RANGE,
    NOMINAL,
    Recalibrated,
    class_thresholds,
    fit_uncertainty,
    metadata,
    recalibrated,
)
from wtml.exporters.graphs import export_graph
from wtml.runtime import metadata as md
from wtml.schema import SchemaError, build

VALUES = np.array([1.0, 2.0, 3.0, 4.0])
"""Each class's value (a grain size, say): the classes ordered by it."""
SPEC = {"sigma": "log_sigma", "value": "value", "by": "value", "log_value": True,
        "stored": "log_std"}
NAMES = ("value", "log_sigma", "probabilities")


def confused(rng, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` windows ``(n, 6)``: the net's inputs (the answer, its log σ, four logits), and
    their classes ``(n,)``. The answer is the named class's value (σ 5 % in ln); the last
    class is named as the one before it about a third of the time."""
    labels = rng.integers(0, 4, n)
    logits = rng.normal(0.0, 1.0, (n, 4))
    logits[np.arange(n), labels] += 2.5
    logits[labels == 3, 2] += 2.0
    named = logits.argmax(1)
    value = VALUES[named] * np.exp(0.05 * rng.standard_normal(n))
    x = np.column_stack([value, np.full(n, np.log(0.05)), logits])
    return x.astype(np.float32), labels


class Passing(nn.Module):
    """The net: ``x, y (batch, 4)``, the first two columns of :func:`confused`'s windows and
    their logits -> (value, log σ, softmax of the logits)."""

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return x[:, 0], x[:, 1], torch.softmax(y, -1)


def inputs(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`confused`'s windows as :class:`Passing` takes them."""
    return np.pad(x[:, :2], ((0, 0), (0, 2))), np.ascontiguousarray(x[:, 2:])


def answers(x: np.ndarray) -> dict[str, np.ndarray]:
    with torch.no_grad():
        out = Passing()(*(torch.tensor(a) for a in inputs(x)))
    return {k: v.double().numpy() for k, v in zip(NAMES, out, strict=True)}


def per_class(err: np.ndarray, half: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """The share of each class's answers inside ``±half``, ``(4,)``."""
    return np.array([np.mean(np.abs(err[labels == k]) <= half[labels == k])
                     for k in range(4)])


def fitted(rng, classes: bool):
    x, labels = confused(rng, 20000)
    out = answers(x)
    spec = SPEC | ({"classes": "probabilities", "class_values": tuple(VALUES)} if classes
                   else {})
    return fit_uncertainty(out, {"value": VALUES[labels]}, [spec], 4, "synthetic",
                           "probabilities", labels)


def test_reaching_the_likely_classes_covers_every_class_where_ranges_of_the_answer_cannot(
        rng):
    fresh, labels = confused(rng, 20000)
    out = answers(fresh)
    err = np.log(out["value"]) - np.log(VALUES[labels])
    # by range of the answer alone: the last class, read as the one before, falls short
    r = fitted(rng, classes=False).intervals[0]
    which = r.range_of(out["value"])
    ranged = np.exp(out["log_sigma"]) * np.asarray(r.scales)[which]
    old = per_class(err, ranged, labels)
    assert old[3] < 0.6 and old[:3].min() > 0.6
    # reaching each class as likely as its threshold: each class at both levels
    u = fitted(rng, classes=True)
    r = u.intervals[0]
    assert r.thresholds[3] < min(r.thresholds[:3])  # the confused class reaches most
    graph = Recalibrated(Passing(), NAMES, u).eval()
    with torch.no_grad():
        got = {k: v.double().numpy() for k, v in zip(
            graph.outputs, graph(*(torch.tensor(a) for a in inputs(fresh))), strict=True)}
    sigma = np.exp(got["log_sigma"])
    wide = r.wide(got["value"], got) * sigma
    for level, half in zip(NOMINAL, (sigma, wide), strict=True):
        np.testing.assert_allclose(per_class(err, half, labels), level, atol=0.025)
    # the classes it is sure of get intervals no wider than by range alone
    sure = labels < 2
    assert np.median(sigma[sure]) <= np.median(ranged[sure])


def test_a_class_interval_gives_the_same_sigma_in_onnx_torch_and_its_numpy_twin(rng, tmp_path):
    u = fitted(rng, classes=True)
    assert build(md.Uncertainty, json.loads(metadata(u))) == u  # what the export writes
    r = u.intervals[0]
    x, _ = confused(rng, 3000)
    graph = Gated(Recalibrated(Passing(), NAMES, u), DomainGate(ZeParts(), 8), (1,)).eval()
    path = tmp_path / "classes.onnx"
    export_graph(graph, 4, path, {"outputs": json.dumps(list(NAMES))}, ("x", "y"))
    feed = dict(zip(("x", "y"), inputs(x), strict=True))
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, feed)
    with torch.no_grad():
        want = [t.numpy() for t in graph(*(torch.tensor(a) for a in feed.values()))]
    assert got[-2].all()  # every window in domain
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=2e-5, atol=2e-6)
    # the numpy twin: log σ = max(log σ_net + ln scale, ln reach of the 68 % thresholds)
    out = answers(x)
    p = recalibrated(out["probabilities"], u)
    np.testing.assert_allclose(got[2], p, atol=2e-5)
    reach = md.class_reach(got[0], got[2], r.class_values, r.thresholds, True)
    twin = np.maximum(out["log_sigma"] + np.log(np.asarray(r.scales))[r.range_of(got[0])],
                      np.log(np.maximum(reach, 1e-30)))
    np.testing.assert_allclose(got[1], twin, atol=2e-5)
    assert (reach > np.exp(twin) * 0.999).mean() > 0.05  # some windows widened by a class
    # the device runtime's 95 % half-width from the graph's outputs
    outputs = dict(zip(NAMES, got[:3], strict=True))
    reach95 = md.class_reach(got[0], got[2], r.class_values, r.thresholds_wide, True)
    width = np.asarray(r.widths)[r.range_of(got[0])]
    np.testing.assert_allclose(r.half_width(got[1], got[0], outputs),
                               np.log(np.maximum(width * np.exp(got[1]), reach95)), atol=1e-6)
    with pytest.raises(ValueError, match="needs the graph's outputs 'value', 'probabilities'"):
        r.wide(got[0])


def test_class_thresholds_are_conformal_quantiles_and_never_where_sigma_suffices(rng):
    """A class covered by its σ alone never widens an interval; one covered by nothing
    reaches at 1 − the conformal quantile of 1 − p over its answers."""
    n = 400
    labels = np.repeat([0, 1], n // 2)
    p = np.column_stack([1 - (q := rng.uniform(0, 1, n)), q])
    value = np.where(labels == 0, VALUES[0], VALUES[0] * 1.001)  # class 1 answered as 0
    err = np.log(value) - np.log(VALUES[labels])
    base = np.full(n, 0.01)  # covers class 0 exactly, never class 1
    tau = class_thresholds(err, base, p, labels, VALUES[:2], True, NOMINAL[0], value)
    assert tau[0] == md.NEVER
    covered = p[labels == 1, 1] >= tau[1]
    assert covered.mean() >= NOMINAL[0] and covered.mean() < NOMINAL[0] + 0.01


def test_a_class_interval_is_checked_and_one_without_classes_reads_as_before():
    rule = {"sigma": "s", "value": "v", "by": "v", "log_value": True, "stored": "log_std",
            "scales": [1.0], "widths": [2.0]}
    old = build(md.IntervalRecalibration, rule)
    assert old.classes == "" and old.wide(np.ones(3)).tolist() == [2.0] * 3
    good = rule | {"classes": "p", "class_values": [1.0, 2.0], "thresholds": [2.0, 0.5],
                   "thresholds_wide": [0.9, 0.1]}
    build(md.IntervalRecalibration, good)
    for bad, key in ((good | {"classes": ""}, "class_values"),
                     (good | {"thresholds": [0.5]}, "thresholds:"),
                     (good | {"thresholds_wide": [0.5, 0.5, 0.5]}, "thresholds_wide"),
                     (good | {"class_values": [0.0, 2.0]}, "class_values"),
                     (good | {"thresholds": [2.5, 0.5]}, "thresholds")):
        with pytest.raises(SchemaError, match=key):
            build(md.IntervalRecalibration, bad)


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.0, 1e-300, 1e-3, 1.0, 1e300]),
       st.floats(0.0, 1.0), st.integers(1, 4))
def test_any_held_out_answers_give_class_thresholds_the_metadata_accepts(seed, sigma, exact,
                                                                        n_classes):
    """Whatever the held-out answers (exact ones, σ that vanishes or overflows, classes with
    too few answers to fit, probabilities of exactly 0 and 1): every scale, width and
    threshold inside the metadata's bounds, and the rule builds and gives 95 % widths of no
    NaN."""
    rng = np.random.default_rng(seed)
    n = 120
    labels = rng.integers(0, n_classes, n)
    value = VALUES[rng.integers(0, 4, n)]
    value = np.where(rng.random(n) < exact, VALUES[labels], value)  # some answers exact
    p = rng.dirichlet(np.ones(4), n)
    p[rng.random(n) < 0.05] = np.eye(4)[rng.integers(0, 4)]  # sure, right or wrong
    out = {"value": value, "log_sigma": np.full(n, np.log(sigma) if sigma else -np.inf),
           "probabilities": p}
    spec = SPEC | {"classes": "probabilities", "class_values": tuple(VALUES)}
    u = fit_uncertainty(out, {"value": VALUES[labels]}, [spec], 2, "hypothesis",
                        "probabilities", labels)
    r = build(md.Uncertainty, json.loads(metadata(u))).intervals[0]
    assert all(0.0 <= t <= md.NEVER for t in (*r.thresholds, *r.thresholds_wide))
    assert min(r.widths) >= 1.0 and all(np.isfinite(r.scales))
    # the graph's σ (its numpy twin) and the runtime's 95 % width of it
    with np.errstate(divide="ignore"):
        log_sigma = np.maximum(
            out["log_sigma"] + np.log(np.asarray(r.scales))[r.range_of(value)],
            np.log(md.class_reach(value, recalibrated(p, u), r.class_values, r.thresholds,
                                  True)))
    graph_out = {"value": value, "log_sigma": log_sigma, "probabilities": recalibrated(p, u)}
    wide = r.wide(value, graph_out)  # inf only where σ underflows below a class's reach
    assert not np.isnan(wide).any()
    # each class with answers enough to fit holds both levels on the answers it was fitted on
    # (to the last bits: a width set at an error is that error's value, then read back through
    # a log std's exp(log σ + ln width); these answers' errors take four values, so tie often)
    err = np.abs(np.log(value) - np.log(VALUES[labels])) * (1 - 1e-9)
    sigma = np.exp(log_sigma)
    half95 = np.exp(r.half_width(log_sigma, value, graph_out))
    assert not np.isnan(half95).any()
    for k in range(n_classes):
        mine = labels == k
        if mine.sum() >= MIN_PER_RANGE:
            assert np.mean(err[mine] <= sigma[mine]) >= NOMINAL[0]
            assert np.mean(err[mine] <= half95[mine]) >= NOMINAL[1]


def test_rows_without_an_answer_leave_the_fit_as_it_is_without_them(rng):
    """Windows whose probabilities, answer and σ are NaN (NaN inputs, which the gate flags)
    tell the fit nothing: the temperature, the top label's map, the ECE before and after, the
    scales, widths and each grade's thresholds are those fitted without them; a truth key no
    spec reads is left alone, and rows all NaN are refused by name."""
    x, labels = confused(rng, 6000)
    out = answers(x)
    spec = SPEC | {"classes": "probabilities", "class_values": tuple(VALUES)}
    truth = {"value": VALUES[labels]}
    clean = fit_uncertainty(out, truth, [spec], 4, "synthetic", "probabilities", labels)
    holes = rng.choice(len(labels), 300, replace=False)
    gaps = {k: v.copy() for k, v in out.items()}
    for v in gaps.values():
        v[holes] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning from a NaN row either
        got = fit_uncertainty(gaps, truth, [spec], 4, "synthetic", "probabilities", labels)
    # a key of the truth that no spec reads (another length) is not touched
    got_more = fit_uncertainty(gaps, truth | {"frequency_hz": np.arange(7.0)}, [spec], 4,
                               "synthetic", "probabilities", labels)
    assert got_more.temperature == got.temperature
    nothing = {k: np.full_like(v, np.nan) for k, v in out.items()}
    with pytest.raises(ValueError, match="none of the 6000 rows of 'probabilities'"):
        fit_uncertainty(nothing, truth, [spec], 4, "synthetic", "probabilities", labels)
    keep = np.setdiff1d(np.arange(len(labels)), holes)
    want = fit_uncertainty({k: v[keep] for k, v in out.items()}, {"value": truth["value"][keep]},
                           [spec], 4, "synthetic", "probabilities", labels[keep])
    for name in ("temperature", "top_slope", "top_bias", "ece_before", "ece_after"):
        assert getattr(got, name) == pytest.approx(getattr(want, name), rel=1e-9), name
    assert got.temperature != pytest.approx(clean.temperature, rel=1e-12)  # the holes mattered
    g, w = got.intervals[0], want.intervals[0]
    for name in ("edges", "scales", "widths", "thresholds", "thresholds_wide"):
        np.testing.assert_allclose(getattr(g, name), getattr(w, name), rtol=1e-9, err_msg=name)
