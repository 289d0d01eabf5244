"""Honest uncertainty (issue 25 §4): the coverage and calibration measures of
``wtml bench coverage`` on synthetic answers whose truth is known, the recalibrations of
``wtml.decoders.recalibration``, and the recalibrated graphs: ONNX against torch, and old
exports refused."""

import dataclasses
import json

import numpy as np
import onnxruntime as ort
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

from wtml.bench.coverage import (
    by_range,
    chance_misses,
    class_table,
    coverage_cell,
    ece_floor,
    exact_hits,
    fluid_sets,
    hits,
    recalibration_text,
    wilson,
)
from wtml.decoders.domain import DomainGate, Gated, ZeParts
from wtml.decoders.recalibration import (
    KEEP,
    MAX_WIDTH,
    NOMINAL,
    Recalibrated,
    conformal_quantile,
    coverage,
    expected_calibration_error,
    fit_scales,
    fit_temperature,
    fit_top_label,
    fit_uncertainty,
    interval,
    level_widths,
    metadata,
    recalibrated,
    tempered,
    top_label,
)
from wtml.exporters.graphs import export_graph
from wtml.runtime import metadata as md
from wtml.schema import SchemaError, build


def gaussian_answers(rng, n: int = 40000):
    """Heteroscedastic answers: σ log-uniform over a decade, errors N(0, σ²)."""
    sigma = np.exp(rng.uniform(np.log(0.1), np.log(1.0), n))
    truth = rng.uniform(0.0, 1.0, n)
    return truth, sigma * rng.standard_normal(n), sigma


def test_coverage_recovers_the_nominal_rates_of_an_honest_sigma(rng):
    truth, err, sigma = gaussian_answers(rng)
    cells = by_range(hits(err, sigma), truth, np.linspace(0, 1, 6))
    for c in cells:  # every quintile and all
        assert c["verdict"] == ["ok", "ok"]
        for share, nominal, (lo, hi) in zip(c["cover"], NOMINAL, c["interval"], strict=True):
            assert abs(share - nominal) < 0.02 and lo <= nominal <= hi


def test_a_sigma_too_small_by_two_is_a_miss_in_every_range(rng):
    truth, err, sigma = gaussian_answers(rng)
    cells = by_range(hits(err, sigma / 2), truth, np.linspace(0, 1, 6))
    for c in cells:
        assert c["verdict"] == ["miss", "miss"]
        # Φ(±0.5) and Φ(±0.98): 38.3 % and 67.3 %
        assert abs(c["cover"][0] - 0.383) < 0.03 and abs(c["cover"][1] - 0.673) < 0.03


def test_too_few_answers_to_tell_are_marked_so_and_no_interval_is_not_counted(rng):
    # 6 and 9 of 10 answers inside: 8 and 5 points off, yet within sampling of 10
    covered = np.stack([np.arange(10) < 6, np.arange(10) < 9], 1).astype(float)
    c = coverage_cell(covered)
    assert c["cover"] == [0.6, 0.9] and c["verdict"] == ["?", "?"]
    assert coverage_cell(np.tile(covered, (100, 1)))["verdict"] == ["miss", "miss"]
    truth, err, sigma = gaussian_answers(rng, 12)
    sigma[:5] = np.nan  # out of domain: no interval
    assert coverage_cell(hits(err, sigma))["n"] == 7
    lo, hi = wilson(7, 10)
    assert lo < 0.7 < hi and wilson(0, 0) == (0.0, 1.0)


def test_grouped_intervals_hold_the_true_rate_where_the_binomial_misses_it():
    """40 specimens of 8 windows whose coverage is 68.27 % on average but each specimen's
    own (beta-distributed, as a specimen's grains set its windows' errors): the Wilson
    interval over the windows leaves the true rate out in 31 % of 400 draws, over their
    worth (``groups``) in 7 %; and most misses called on windows are not called on groups."""
    rng = np.random.default_rng(7)
    held = {"windows": 0, "groups": 0}
    verdicts = {"windows": 0, "groups": 0}
    draws = 400
    for _ in range(draws):
        own = rng.beta(2 * NOMINAL[0], 2 * (1 - NOMINAL[0]), 40)
        hit = (rng.random((40, 8)) < own[:, None]).astype(float).ravel()
        covered = np.stack([hit, hit], 1)
        groups = np.repeat(np.arange(40), 8)
        for key, cell in (("windows", coverage_cell(covered)),
                          ("groups", coverage_cell(covered, groups))):
            lo, hi = cell["interval"][0]
            held[key] += lo <= NOMINAL[0] <= hi
            verdicts[key] += cell["verdict"][0] == "miss"
    assert held["windows"] / draws < 0.8
    assert 0.92 <= held["groups"] / draws <= 0.99
    assert verdicts["groups"] < verdicts["windows"] / 3
    cells = by_range(covered, np.tile(np.linspace(0, 1, 8), 40), np.linspace(0, 1, 3), groups)
    assert [c["n"] for c in cells] == [160, 160, 320]
    assert all(c["n_effective"][0] < c["n"] / 2 for c in cells)


def test_a_95_percent_level_whose_misses_may_be_whole_specimens_is_not_called_early():
    """48 specimens of 4 windows at nominal rates. Each specimen (5 %) missing both levels in
    all its windows, as a grain the decoder misreads would: the binomial calls ±1.96σ a miss
    in ~28 % of draws, the count per level in at most 6 %. Each specimen's own rate drawn
    from a beta of mean 95 %: a count read from a few misses called 7.5 % (one miss is enough
    to read it from), counting by groups until the misses show in 5 of them at most 5 %. And
    192 of 192 covered is judged as 191 of 192: by the 48 groups."""
    rng = np.random.default_rng(0)
    groups = np.repeat(np.arange(48), 4)
    called = {"windows": 0, "groups": 0, "beta": 0}
    draws = 1000
    for _ in range(draws):
        bad = rng.random(48) < 0.05
        inner = (rng.random((48, 4)) < NOMINAL[0] / 0.95) & ~bad[:, None]
        covered = np.stack([inner.ravel(), np.repeat(~bad, 4)], 1).astype(float)
        called["windows"] += coverage_cell(covered)["verdict"][1] == "miss"
        called["groups"] += coverage_cell(covered, groups)["verdict"][1] == "miss"
    beta = np.random.default_rng(0)
    for _ in range(draws):
        own = beta.beta(2 * NOMINAL[1], 2 * (1 - NOMINAL[1]), 48)
        hit = (beta.random((48, 4)) < own[:, None]).astype(float).ravel()
        called["beta"] += coverage_cell(np.stack([hit, hit], 1), groups)["verdict"][1] == "miss"
    assert called["windows"] / draws > 0.2
    assert called["groups"] / draws <= 0.06
    assert called["beta"] / draws <= 0.05
    every = np.stack([(rng.random(192) < NOMINAL[0]).astype(float), np.ones(192)], 1)
    one_out = every.copy()
    one_out[0, 1] = 0.0
    for covered in (every, one_out):
        cell = coverage_cell(covered, groups)
        assert cell["n_effective"][1] == 48 and cell["verdict"][1] == "?"
        assert coverage_cell(covered)["verdict"][1] == "miss"
    with pytest.raises(ValueError, match="one label per row"):
        coverage_cell(every, groups[:-1])


def test_a_scale_fitted_on_held_out_answers_restores_the_coverage(rng):
    """σ too small by 2× overall, and by 1.5× or 3× depending on the range: the scales per
    range of the answer bring fresh answers back to nominal in every range, with a Gaussian's
    95 % width."""
    truth, err, sigma = gaussian_answers(rng)
    scale, width = level_widths(np.abs(err) / (sigma / 2))
    assert scale == pytest.approx(2.0, rel=0.03) and width == pytest.approx(1.96, rel=0.03)
    wrong = np.where(truth < 0.5, 1.5, 3.0)
    edges, scales, widths = fit_scales(err, sigma / wrong, truth + 0.01 * err, 2)
    assert len(edges) == 1 and abs(edges[0] - 0.5) < 0.02
    assert scales == pytest.approx([1.5, 3.0], rel=0.04)
    assert widths == pytest.approx([1.96, 1.96], rel=0.04)
    # too few answers in domain to fit (a decoder that flags nearly all): σ left as it is
    assert [x.tolist() for x in fit_scales(err[:30], sigma[:30], truth[:30], 3)] == [
        [], [1.0], [md.WIDE]]
    truth2, err2, sigma2 = gaussian_answers(np.random.default_rng(1))
    which = (truth2 >= edges[0]).astype(int)
    back = sigma2 / np.where(truth2 < 0.5, 1.5, 3.0) * scales[which]
    for c in by_range(hits(err2, back, widths[which]), truth2, np.linspace(0, 1, 6)):
        assert c["verdict"] == ["ok", "ok"]


def test_a_width_per_level_covers_both_levels_where_errors_are_not_gaussian(rng):
    """Errors Laplace (heavy-tailed: q95/q68 of |err| is ln 20 / ln(1/0.3173) = 2.61) below
    0.5 and uniform (light: 0.95 / 0.6827 = 1.39) above: no single σ per range holds both
    of a range's levels with the Gaussian 1.96σ, and the fitted 95 % width per range does, on
    fresh answers, in every quintile."""
    def answers(g, n=40000):
        truth = g.uniform(0.0, 1.0, n)
        err = np.where(truth < 0.5, g.laplace(0.0, 1.0, n), g.uniform(-1.0, 1.0, n))
        return truth, err, np.ones(n)

    truth, err, sigma = answers(rng)
    edges, scales, widths = fit_scales(err, sigma, truth, 2)
    assert widths == pytest.approx([np.log(20) / -np.log(1 - 0.6827), 0.95 / 0.6827],
                                   rel=0.03)
    truth2, err2, sigma2 = answers(np.random.default_rng(1))
    which = np.searchsorted(edges, truth2, side="right")
    fitted = by_range(hits(err2, sigma2 * scales[which], widths[which]), truth2,
                      np.linspace(0, 1, 6))
    assert all(c["verdict"] == ["ok", "ok"] for c in fitted)
    gaussian = by_range(hits(err2, sigma2 * scales[which]), truth2, np.linspace(0, 1, 6))
    # the quintiles of one law each (the middle one mixes them, and the whole): Laplace
    # below (1.96σ holds too little), uniform above (1.96σ holds everything)
    assert all(gaussian[k]["verdict"] == ["ok", "miss"] for k in (0, 1, 3, 4))
    assert gaussian[0]["cover"][1] < 0.91 and gaussian[4]["cover"][1] == 1.0


def synthetic_classifier(rng, n: int, sharpen: float = 1.0):
    """Probabilities from random logits, labels drawn from them (a calibrated classifier);
    ``sharpen`` > 1: the same labels under logits × sharpen (over-confident)."""
    logits = rng.normal(0.0, 1.5, (n, 5))
    p = torch.softmax(torch.tensor(logits), -1).numpy()
    labels = (p.cumsum(1) < rng.random(n)[:, None]).sum(1)
    return torch.softmax(torch.tensor(sharpen * logits), -1).numpy(), labels


def test_ece_of_a_calibrated_classifier_is_near_zero_and_of_an_overconfident_one_is_not(rng):
    p, labels = synthetic_classifier(rng, 50000)
    ece, curve = expected_calibration_error(p, labels)
    assert ece < 0.01 and curve["count"].sum() == 50000
    assert ece < ece_floor(p.max(1), draws=50)[1] * 2
    sharp, labels = synthetic_classifier(rng, 50000, sharpen=3.0)
    assert expected_calibration_error(sharp, labels)[0] > 0.05


def test_class_table_judges_the_in_domain_windows_against_the_target(rng):
    """The ECE is of the answers the classifier gives in its domain (flagged ones claim
    nothing, as a flagged σ), ✗ only above both the 2 % target and a calibrated classifier's
    95th percentile on as many answers; ? above the target within that percentile."""
    p, labels = synthetic_classifier(rng, 40000)
    wrong = np.zeros_like(p)
    wrong[np.arange(len(p)), (labels + 1) % 5] = 1.0  # sure and wrong
    flagged = np.arange(len(p)) % 4 == 0
    mixed = np.where(flagged[:, None], wrong, p)
    sharp, sharp_labels = synthetic_classifier(rng, 40000, sharpen=3.0)
    rows = [{"name": "calibrated, its flagged quarter sure and wrong", "kind": "test shard",
             "labels": labels, "before": mixed, "after": mixed, "inside": ~flagged,
             "flagged": 0.25},
            {"name": "over-confident", "kind": "held out", "labels": sharp_labels,
             "before": sharp, "after": sharp, "inside": np.ones(len(sharp), bool),
             "flagged": 0.0},
            {"name": "calibrated, 60 windows", "kind": "held out", "labels": labels[:60],
             "before": p[:60], "after": p[:60], "inside": np.ones(60, bool), "flagged": 0.0}]
    lines, out = class_table(rows, "T = 1")
    assert [r["verdict"] for r in out] == ["ok", "miss", "?"]
    assert out[0]["windows"] == 30000 and out[0]["ece"] < 0.01
    assert expected_calibration_error(mixed, labels)[0] > 0.2  # what counting them would say
    assert out[1]["ece"] > 0.05 and out[2]["ece"] > 0.02
    assert "✗" in lines[3] and "?" in lines[4] and "25.0 %" in lines[2]


def test_fluid_device_rows_are_held_out_only_where_they_leave_the_trained_spread():
    """The default scene measures its sphere: issue 21's spread and the radius alone are off
    its physics. For a decoder trained with the radius declared issue 21's spread is its own
    scene; the radius alone (a narrower prior than it trained on) stays held out."""
    from pathlib import Path

    from wtml.scenes import load_scene

    configs = Path(__file__).resolve().parents[1] / "configs/scenes"
    kinds = {name: [r.kind for r in fluid_sets({"data": "unused"}, load_scene(
        configs / f"{name}.yaml"), None, {"fluid": 10}, 0)[2:]]
        for name in ("fluid", "fluid_radius")}
    assert kinds == {"fluid": ["held out"] * 2, "fluid_radius": ["in family", "held out"]}


def test_a_calibrated_classifier_is_called_a_miss_about_one_time_in_twenty():
    """The floor is drawn from the answers' own top probabilities, below 0.5 too (five
    classes): 200 calibrated classifiers of 60 answers are called ✗ about 5 % of the time
    (a floor drawn as two classes had called 25 %)."""
    verdicts = []
    for seed in range(200):
        p, labels = synthetic_classifier(np.random.default_rng(seed), 60)
        assert (p.max(1) < 0.5).mean() > 0.2
        verdicts.append(class_table([{"name": "calibrated", "kind": "test shard",
                                      "labels": labels, "before": p, "after": p,
                                      "inside": np.ones(60, bool), "flagged": 0.0}],
                                    1.0)[1][0]["verdict"])
    assert 2 <= verdicts.count("miss") <= 22 and verdicts.count("ok") == 0


def test_an_ece_floor_counts_windows_that_share_their_answer_as_one():
    """60 calibrated answers each copied to 8 windows (a specimen's windows failing
    together): judged as 480 independent windows every one is called ✗; as what they are
    worth (their groups), about one in twenty."""
    verdicts = {False: [], True: []}
    for seed in range(100):
        p, labels = synthetic_classifier(np.random.default_rng(seed), 60)
        row = {"name": "copied", "kind": "test shard", "labels": np.repeat(labels, 8),
               "before": np.repeat(p, 8, 0), "after": np.repeat(p, 8, 0),
               "inside": np.ones(480, bool), "flagged": 0.0}
        for grouped in (False, True):
            out = class_table([row | ({"groups": np.repeat(np.arange(60), 8)} if grouped
                                      else {})], 1.0)[1][0]
            verdicts[grouped].append(out["verdict"])
    assert out["worth"] == pytest.approx(60, rel=0.05)  # G / (G − 1): 59
    assert verdicts[False].count("miss") > 90
    assert 1 <= verdicts[True].count("miss") <= 15


def test_temperature_scaling_lowers_the_ece_of_an_overconfident_classifier(rng):
    p, labels = synthetic_classifier(rng, 20000, sharpen=3.0)
    t = fit_temperature(p[:10000], labels[:10000])
    assert t == pytest.approx(3.0, rel=0.1)
    before = expected_calibration_error(p[10000:], labels[10000:])[0]
    after = expected_calibration_error(tempered(p[10000:], t), labels[10000:])[0]
    assert after < 0.025 and 0.05 < before and after < before / 4
    assert np.array_equal(tempered(p, t).argmax(1), p.argmax(1))  # the answer stays


def stated_and_true(rng, n: int, slope: float, bias: float):
    """Five-class answers whose top probability t is uniform on [0.3, 0.999] (the other four
    (1 - t)/4 each) and right with probability sigmoid(slope·logit t + bias)."""
    t = rng.uniform(0.3, 0.999, n)
    top = rng.integers(0, 5, n)
    p = np.repeat(((1 - t) / 4)[:, None], 5, 1)
    p[np.arange(n), top] = t
    right = rng.random(n) < 1 / (1 + np.exp(-(slope * np.log(t / (1 - t)) + bias)))
    labels = np.where(right, top, (top + rng.integers(1, 5, n)) % 5)
    return p, labels


def test_the_top_labels_map_takes_a_shape_that_one_temperature_cannot(rng):
    """Answers right less often than stated in the middle and as often near certainty (a
    bias on the top label's logit): a temperature leaves an ECE over 2 %, the map after it
    under 1 % on fresh answers; the map keeps the likeliest class and sums to 1, and on a
    calibrated classifier it is near the identity."""
    p, labels = stated_and_true(rng, 40000, 1.0, -0.6)
    fresh, fresh_labels = stated_and_true(rng, 40000, 1.0, -0.6)
    t = fit_temperature(p, labels)
    slope, bias = fit_top_label(tempered(p, t), labels)
    tempered_only = expected_calibration_error(tempered(fresh, t), fresh_labels)[0]
    mapped = top_label(tempered(fresh, t), slope, bias)
    assert tempered_only > 0.02 and expected_calibration_error(mapped, fresh_labels)[0] < 0.01
    assert np.array_equal(mapped.argmax(1), fresh.argmax(1))
    np.testing.assert_allclose(mapped.sum(1), 1.0, rtol=1e-12)
    calibrated, labels = synthetic_classifier(rng, 40000)
    # the others keep their proportions (unequal ones: the four after the top, in order)
    rest = np.argsort(-calibrated, 1)[:, 1:]
    moved = np.take_along_axis(top_label(calibrated, 1.3, -0.4), rest, 1)
    before = np.take_along_axis(calibrated, rest, 1)
    np.testing.assert_allclose(moved / moved[:, :1], before / before[:, :1], rtol=1e-9)
    assert np.abs(moved - before).max() > 0.05
    slope, bias = fit_top_label(calibrated, labels)
    assert abs(slope - 1) < 0.05 and abs(bias) < 0.05
    ranked = np.sort(calibrated, 1)
    apart = np.log(ranked[:, -1] / ranked[:, -2]) > 2 * KEEP  # the identity, but for near-ties
    np.testing.assert_allclose(top_label(calibrated, 1.0, 0.0)[apart], calibrated[apart],
                               atol=1e-12)
    np.testing.assert_allclose(top_label(calibrated, 1.0, 0.0), calibrated, atol=1e-4)
    lowered = top_label(calibrated, 1.0, -5.0)  # would sink the top below the second
    assert np.array_equal(lowered.argmax(1), calibrated.argmax(1))
    # a tie for the top: the first class, the second just below it, as a near-tie gives
    tie = top_label(np.array([[0.4, 0.4, 0.2]]), 1.3, 0.5)
    near = top_label(np.array([[0.4 + 1e-12, 0.4, 0.2]]), 1.3, 0.5)
    np.testing.assert_allclose(tie, near, atol=1e-9)
    assert tie[0, 0] > tie[0, 1] > tie[0, 2] and tie[0, 0] > 0.45
    assert fit_top_label(p[:200][p[:200].argmax(1) == labels[:200]],
                         labels[:200][p[:200].argmax(1) == labels[:200]]) == (1.0, 0.0)


def test_the_top_labels_map_is_stated_with_its_temperature_and_an_older_export_has_none():
    """``top_slope`` and ``top_bias`` come together and only beside a temperature; an
    export's metadata without them (before the map) reads as tempered only."""
    base = {"fitted_on": "x", "probabilities": "p", "temperature": 1.2}
    old = build(md.Uncertainty, base)
    assert old.top_slope is None
    p = np.array([[0.7, 0.2, 0.1]])
    np.testing.assert_allclose(recalibrated(p, old), tempered(p, 1.2))
    both = build(md.Uncertainty, base | {"top_slope": 1.1, "top_bias": -0.2})
    np.testing.assert_allclose(recalibrated(p, both), top_label(tempered(p, 1.2), 1.1, -0.2))
    assert recalibration_text(old) == "T = 1.2"  # the coverage bench's words for each
    assert recalibration_text(both) == "T = 1.2, top label: slope 1.1, bias -0.2"
    with pytest.raises(SchemaError, match="top_bias"):
        build(md.Uncertainty, base | {"top_slope": 1.1})
    with pytest.raises(SchemaError, match="top_slope"):
        build(md.Uncertainty, {"fitted_on": "x", "top_slope": 1.1, "top_bias": 0.0})
    with pytest.raises(SchemaError, match="top_slope"):
        build(md.Uncertainty, base | {"top_slope": 0.0, "top_bias": 0.0})


class Toy(nn.Module):
    """A stand-in decoder: a value, its std, a log std and class probabilities from
    ``(x, y)`` ``(batch, 3)``."""

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, ...]:
        value = x.sum(-1)
        return (value, torch.exp(y.mean(-1)), y[:, 0] - 1.0,
                torch.softmax(torch.stack([x[:, 0], y[:, 1], x[:, 2] - y[:, 2]], -1) * 4, -1))


def test_a_recalibrated_graph_gives_the_same_sigmas_and_probabilities_in_onnx_and_torch(
        rng, tmp_path):
    names = ("value", "sigma", "log_sigma", "probabilities")
    x = rng.normal(0, 1, (4000, 3)).astype(np.float32)
    y = rng.normal(0, 0.3, (4000, 3)).astype(np.float32)
    x[:40, 0] = y[:40, 1] = 1.0  # the first two classes tied: the graph's ArgMax as numpy's
    net = Toy()
    with torch.no_grad():
        out = {k: v.double().numpy() for k, v in zip(names, net(torch.tensor(x),
                                                                torch.tensor(y)), strict=True)}
    # truths whose errors are 2× the net's σ, 3× its exp(log σ), and a second value without σ
    truth = {"value": out["value"] - 2 * out["sigma"] * rng.standard_normal(4000)}
    specs = [{"sigma": "sigma", "value": "value", "by": "value", "log_value": False,
              "stored": "std"},
             {"sigma": "log_sigma", "value": "value", "by": "value", "log_value": False,
              "stored": "log_std"},
             {"sigma": "value_sigma", "value": "value", "by": "value", "log_value": False,
              "stored": "none"}]
    labels = (out["probabilities"].cumsum(1) < rng.random(4000)[:, None]).sum(1)
    u = fit_uncertainty(out, truth, specs, 3, "synthetic", "probabilities", labels)
    assert len(u.intervals[0].scales) == 3 and u.temperature is not None
    assert u.top_slope is not None
    u = dataclasses.replace(u, top_slope=1.3, top_bias=-0.5)  # a map far from the identity
    assert build(md.Uncertainty, json.loads(metadata(u))) == u  # what the export writes
    graph = Recalibrated(net, names, u).eval()
    assert graph.outputs == (*names, "value_sigma")
    gated = Gated(graph, DomainGate(ZeParts(), 6), (1, 2, 4)).eval()  # every input inside
    path = tmp_path / "toy.onnx"
    export_graph(gated, 3, path, {"outputs": json.dumps(list(graph.outputs))}, ("x", "y"))
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run(None, {"x": x, "y": y})
    with torch.no_grad():
        want = [t.numpy() for t in gated(torch.tensor(x), torch.tensor(y))]
    assert len(got) == len(want) == 7 and got[-2].all()
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=2e-5, atol=1e-7)
    # σ scaled per range of the answer, in both
    r = u.intervals[0]
    which = np.searchsorted(r.edges, out["value"], side="right")
    np.testing.assert_allclose(got[1], out["sigma"] * np.array(r.scales)[which], rtol=2e-5)
    np.testing.assert_allclose(got[4], np.array(u.intervals[2].scales)[which], rtol=2e-5)
    # the 95 % half-width the device runtime makes of the metadata: width × σ of σ's range,
    # ln width + log σ for a log std; the fitted widths near 1.96 (Gaussian errors)
    np.testing.assert_allclose(r.half_width(got[1], got[0]),
                               got[1] * np.array(r.widths)[which], rtol=1e-6)
    log_rule = u.intervals[1]
    np.testing.assert_allclose(log_rule.half_width(got[2], got[0]) - got[2],
                               np.log(np.array(log_rule.widths))[
                                   np.searchsorted(log_rule.edges, out["value"], "right")],
                               atol=1e-6)
    assert all(abs(w - 1.96) < 0.2 for w in r.widths)
    np.testing.assert_allclose(got[3], recalibrated(out["probabilities"], u), atol=2e-5)
    assert np.abs(got[3] - tempered(out["probabilities"], u.temperature)).max() > 0.02


def test_the_bayes_rows_score_the_exact_posterior_on_the_in_family_sets_only():
    """``wtml bench coverage``'s best-achievable fluid rows: the exact posterior on the
    inputs the export gets (Ze's parts, T rebuilt from its float32 parts), on the sets of
    its trained scene only, two interval forms per value, each covering near its nominal
    rates over the prior (300 draws: within 8 points)."""
    from conftest import FLUID_SMALL

    from wtml.bench.coverage import RecordSet, fluid_bayes_rows
    from wtml.physics.twoport import flat_parts

    def made(seed):
        def make():
            d = FLUID_SMALL.simulate(300, np.random.default_rng(seed))
            return ((d["ze"].real, d["ze"].imag, *flat_parts(d["t"])),
                    {"eta": d["eta"], "rho": d["rho"]})
        return make

    sets = [RecordSet("fresh", "in family", made(1)), RecordSet("off", "held out", made(2))]
    rows = fluid_bayes_rows(FLUID_SMALL, sets, progress=lambda _: None)
    assert set(rows) == {"eta", "rho"}
    for value in rows.values():
        assert [(r["name"], r["label"]) for r in value] == [
            ("fresh", "Bayes posterior: mean ± zσ"), ("fresh", "Bayes posterior: central credible")]
        for r in value:
            cell = coverage_cell(r["hits"])
            assert cell["n"] == 300
            assert np.allclose(cell["cover"], NOMINAL, atol=0.08), (r["label"], cell["cover"])


def test_a_fluid_export_carries_its_intervals_and_an_old_one_is_refused(flow):
    """The fluid decoder's graph adds the std of ln η and of ρ, per range of η, and says so in
    its metadata; a decoder graph without ``uncertainty`` (an export of a wtml before issue
    25) is refused, naming the key."""
    from wtml.decoders.fluid import load_fluid_net
    from wtml.runtime.predict import load_export
    from wtml.scenes import scene_from_dict

    folder = flow[0] / "export"
    decoder, classical = load_export(folder)
    assert decoder.outputs == ["eta", "rho", *md.FLUID_SIGMAS]
    assert classical.outputs == ["eta", "rho"] and classical.uncertainty is None
    u = decoder.uncertainty
    assert [r.sigma for r in u.intervals] == list(md.FLUID_SIGMAS)
    assert all(r.stored == "none" and r.by == "eta" for r in u.intervals)
    # a 95 % width per range, and both levels met on the held-out answers they were fitted on
    for r in u.intervals:
        assert len(r.widths) == len(r.scales) and min(r.widths) >= 1.0
        assert np.allclose(r.coverage_after, NOMINAL, atol=0.02), (r.sigma, r.coverage_after)
    net, scene = load_fluid_net(str(flow[1]))
    data = scene_from_dict(scene).simulate(200, np.random.default_rng(5))
    from wtml.physics.twoport import flat_parts

    inputs = (data["ze"].real, data["ze"].imag, *flat_parts(data["t"]))
    got = decoder.run(*inputs)
    with torch.no_grad():
        want = Recalibrated(net, ("eta", "rho"), u)(
            *(torch.tensor(np.asarray(a), dtype=torch.float32) for a in inputs))
    for name, w in zip(decoder.outputs, want, strict=True):
        inside = got["in_domain"]
        np.testing.assert_allclose(got[name][inside], w.numpy()[inside], rtol=2e-4)
        assert np.isnan(got[name][~inside]).all() or name in ("eta", "rho")
    # the 95 % half-widths beside them, each by the range of η (not of its own value)
    got |= decoder.half_widths(got)
    for name, r in decoder.intervals.items():
        np.testing.assert_array_equal(got[name], got[r.sigma] * r.wide(got["eta"]))
    assert set(decoder.intervals) == {f"{s}_95" for s in md.FLUID_SIGMAS}
    props = dict(decoder.metadata)
    del props["uncertainty"]
    with pytest.raises(SchemaError, match="metadata uncertainty: missing.*export it again"):
        md.graph_metadata(props, "model.onnx")
    with pytest.raises(SchemaError, match="a classical graph has no recalibration"):
        md.graph_metadata(dict(classical.metadata) | {"uncertainty": decoder.metadata[
            "uncertainty"]}, "classical.onnx")


def test_the_95_percent_widths_are_checked_and_an_export_without_them_reads_as_gaussian():
    """The metadata's widths: one per range or none (an export made before them: 1.96 in
    every range), each >= 1 (a 95 % interval no narrower than the 68 % one); the range of an
    answer found as the graph finds it (float32, NaN in the first)."""
    rule = {"sigma": "sigma", "value": "d", "by": "d", "log_value": False, "stored": "std",
            "edges": [0.1, 0.2], "scales": [1.0, 2.0, 3.0]}
    old = build(md.IntervalRecalibration, rule)
    by = np.array([0.05, 0.1, 0.15, 0.25, np.nan])
    np.testing.assert_array_equal(old.wide(by), [1.96] * 5)
    new = build(md.IntervalRecalibration, rule | {"widths": [1.5, 1.7, 2.5]})
    np.testing.assert_array_equal(new.wide(by), [1.5, 1.7, 1.7, 2.5, 1.5])
    assert new.wide(0.15) == 1.7  # one answer: one width
    np.testing.assert_allclose(new.half_width(np.full(5, 2.0), by), [3.0, 3.4, 3.4, 5.0, 3.0])
    # float32, as the graph compares: just below the edge in float64, at it in float32
    assert new.wide(np.array([np.nextafter(0.2, 0.0)]))[0] == 2.5
    with pytest.raises(SchemaError, match=r"widths: must hold one 95 % width per range"):
        build(md.IntervalRecalibration, rule | {"widths": [1.5, 1.7]})
    with pytest.raises(SchemaError, match="widths"):
        build(md.IntervalRecalibration, rule | {"widths": [1.5, 0.9, 2.0]})


def test_the_conformal_quantile_is_the_finite_sample_rank_and_the_widths_hold_it(rng):
    """q at level p of n scores is the ⌈(n+1)p⌉-th smallest (the largest beyond n); the
    fitted scale and width hold at least that rank's share of the answers they were fitted on
    at both levels (the width rounded up, never a row short), and stay loadable (width
    <= MAX_WIDTH) where most errors vanish."""
    z = np.arange(1.0, 11.0)
    assert conformal_quantile(z[::-1], 0.6827) == 8 and conformal_quantile(z, 0.95) == 10
    assert conformal_quantile(np.array([3.0]), 0.6827) == 3.0
    for n in (37, 110, 400):
        for _ in range(100):
            z = np.abs(rng.standard_t(3, n)) * rng.uniform(0.1, 10)
            scale, width = level_widths(z)
            for level, half in zip(NOMINAL, (scale, scale * width), strict=True):
                assert np.sum(z <= half) >= min(n, np.ceil((n + 1) * level)), (n, level)
    exact = np.r_[np.zeros(280), np.linspace(0.1, 1.0, 120)]  # 70 % of answers exact
    scale, width = level_widths(exact)
    assert 1.0 <= width <= MAX_WIDTH and scale * width >= conformal_quantile(exact, 0.95)
    rule = {"sigma": "s", "value": "v", "by": "v", "log_value": False, "stored": "none",
            "scales": [scale], "widths": [width]}
    assert build(md.IntervalRecalibration, rule).wide(np.zeros(1))[0] == width


def test_the_stated_coverage_finds_each_answers_range_as_the_graph_does(rng):
    """Answers that float32 rounds onto a range's edge fall in the upper range in the graph
    (``by >= edge`` in float32) and so in ``coverage_after``, which would be another share if
    it were found in float64 (each half's errors are of another size)."""
    by = 1.0 + np.arange(-200, 200) * 1e-12  # every one 1.0 in float32
    err = np.r_[rng.normal(0, 3.0, 200), rng.normal(0, 1.0, 200)]
    spec = {"sigma": "s", "value": "v", "by": "v", "log_value": False, "stored": "none"}
    fitted = interval(spec, {"v": by, "s": np.ones(400)}, by - err, n_ranges=2)
    assert len(fitted.edges) == 1 and by[199] < fitted.edges[0] <= by[200]
    assert np.float32(fitted.edges[0]) == np.float32(1.0)
    assert np.all(fitted.range_of(by) == 1)
    upper = coverage(err, np.full(400, fitted.scales[1]), fitted.widths[1])
    assert fitted.coverage_after == pytest.approx(upper)
    split = np.r_[np.zeros(200, int), np.ones(200, int)]
    apart = coverage(err, np.asarray(fitted.scales)[split], np.asarray(fitted.widths)[split])
    assert abs(apart[0] - upper[0]) > 0.05


def test_the_coverage_table_scores_the_recalibrated_95_percent_interval_with_its_width(rng):
    """``wtml bench coverage``'s table: the raw σ's 95 % interval is ±1.96σ, the export's is
    ± its fitted width; uniform errors (q95/q68 = 1.39) are a miss at 1.96σ (all covered)
    and nominal at their width."""
    from wtml.bench.coverage import interval_table

    truth, err = rng.uniform(0, 1, 20000), rng.uniform(-1, 1, 20000)
    row = {"name": "uniform", "kind": "synthetic", "truth": truth, "err": err, "groups": None,
           "sigma": np.full(20000, 0.6827), "wide": np.full(20000, 0.95 / 0.6827),
           "raw": np.full(20000, 0.6827), "flagged": 0.0}
    rule = build(md.IntervalRecalibration, {"sigma": "sigma", "value": "distance",
                                            "by": "distance",
                                            "log_value": False, "stored": "std",
                                            "scales": [1.0], "widths": [0.95 / 0.6827]})
    _, rows = interval_table("toy", rule, [row])
    raw, fitted = rows
    assert raw["sigma"] == "raw" and raw["all"]["cover"][1] == 1.0
    assert raw["all"]["verdict"] == ["ok", "miss"]
    assert fitted["all"]["verdict"] == ["ok", "ok"]
    assert abs(fitted["all"]["cover"][1] - 0.95) < 0.01


def test_the_table_tells_a_bias_from_a_spread(rng):
    """The interval table's err/σ column: errors off by 0.8σ read a median of +0.8 and a
    spread of 1; errors 1.3 times as wide as σ, a median of 0 and a spread of 1.3; the
    answers without a σ (flagged) are left out of both, and a row of no answers reads "–"."""
    from wtml.bench.coverage import interval_table, shape_of

    n = 20000
    truth, sigma = rng.uniform(0, 1, n), np.full(n, 0.5)
    sigma[::10] = np.nan
    rule = build(md.IntervalRecalibration, {"sigma": "sigma", "value": "distance",
                                            "by": "distance", "log_value": False,
                                            "stored": "std", "scales": [1.0],
                                            "widths": [1.96]})
    rows = [{"name": name, "kind": "test shard", "truth": truth, "err": err, "groups": None,
             "sigma": sigma, "wide": np.full(n, 1.96), "raw": raw, "flagged": 0.1}
            for name, err, raw in (("off", rng.normal(0.4, 0.5, n), 2 * sigma),
                                   ("wide", rng.normal(0.0, 0.65, n), None))]
    lines, out = interval_table("toy", rule, rows)
    (raw, off, wide) = out
    assert raw["sigma"] == "raw" and abs(raw["z_median"] - 0.4) < 0.02
    assert abs(off["z_median"] - 0.8) < 0.03 and abs(off["z_spread"] - 1.0) < 0.03
    assert abs(wide["z_median"]) < 0.03 and abs(wide["z_spread"] - 1.3) < 0.04
    assert "err/σ: median, spread" in lines[2]
    assert lines[5].split(" | ")[5] == f"{off['z_median']:+.2f}, {off['z_spread']:.2f}"
    # by hand, skewed: the median and the spread about it, not a mean or a standard deviation
    assert shape_of(np.array([0, 0, 0, 1, 100.0]), np.ones(5)) == (0.0, pytest.approx(0.7308))
    # the answers hits() judges: an infinite σ's left out, a zero σ's off by inf
    assert shape_of(np.array([0.1, -0.2, 0.3, 5, 0]), np.array([0.1, 0.1, 0.1, np.inf, 0.1])
                    ) == (pytest.approx(0.5), pytest.approx(2.5))
    assert shape_of(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))[0] == np.inf
    assert shape_of(np.ones(3), np.full(3, np.nan)) is None
    rows[0]["sigma"], rows[0]["raw"] = np.full(n, np.nan), None  # every answer flagged
    lines, out = interval_table("toy", rule, rows[:1])
    assert lines[4].split(" | ")[5] == "–" and out[0]["z_median"] is None


def _miss_chance(m: int, level: int) -> float:
    """P(✗) of one cell of ``m`` independent answers of an exact interval at ``level``: the
    binomial law of its hits, each count judged by :func:`coverage_cell`."""
    from scipy.stats import binom

    judged = [coverage_cell(np.repeat((np.arange(m) < k).astype(float)[:, None], 2, 1)
                            )["verdict"][level] == "miss" for k in range(m + 1)]
    return float(binom.pmf(np.arange(m + 1), m, NOMINAL[level])[judged].sum())


def test_an_exact_intervals_misses_by_chance_are_the_binomial_laws(rng):
    """chance_misses on five ranges of 150 answers: its mean ✗ count over 3000 draws is the
    sum of each cell's binomial chance of a ✗ (about 5 % per cell of ~150 answers at either
    level; for the 750 together 5 % at 68 %, nearly none at 95 %), within 4 standard errors;
    answers without an interval (NaN) stay without one, so 15 answered of 750 (below
    MIN_VERDICT in every cell) earn none; answers in 4 groups are worth 4 (no ✗ ever), where
    the same answers alone earn some."""
    truth = rng.uniform(0, 1, 750)
    edges = np.linspace(0, 1, 6)
    inner = np.searchsorted(edges[1:-1], truth, side="right")
    sizes = [*np.bincount(inner, minlength=5), 750]
    expected = sum(_miss_chance(int(m), level) for m in sizes for level in (0, 1))
    drawn = chance_misses(np.zeros((750, 2)), truth, edges, draws=3000, seed=1)
    assert drawn.shape == (3000,) and drawn.min() >= 0 and drawn.max() <= 12
    assert 0.4 < expected < 0.8
    assert abs(drawn.mean() - expected) < 4 * drawn.std() / np.sqrt(3000)
    covered = np.full((750, 2), np.nan)
    covered[:15] = 1.0
    assert not chance_misses(covered, truth, edges, draws=200).any()
    one = np.array([0.0, 1.0])
    groups = np.repeat(np.arange(4), 50)
    assert not chance_misses(np.zeros((200, 2)), truth[:200], one, groups, draws=300).any()
    assert chance_misses(np.zeros((200, 2)), truth[:200], one, draws=300).mean() > 0.1


def test_an_exact_intervals_hits_are_nested_at_their_nominal_rates(rng):
    """exact_hits: the 95 % interval holds every answer the 68 % one does, each level at its
    nominal rate (200000 answers: within 0.4 points), rows without an answer NaN at both."""
    answered = np.ones(200_000, bool)
    answered[::10] = False
    drawn = exact_hits(answered, rng)
    assert np.isnan(drawn[~answered]).all() and np.isfinite(drawn[answered]).all()
    kept = drawn[answered]
    assert np.all(kept[:, 0] <= kept[:, 1])
    np.testing.assert_allclose(kept.mean(0), NOMINAL, atol=0.004)


def test_the_coverage_table_counts_its_misses_against_chance(rng):
    """A σ too small by a third misses beyond what an exact interval earns by chance in the
    table's count (none of the draws reach it) and its row is named beyond its own chance;
    the honest σ of the same answers does neither; the rows carry their ✗ and chance's
    median and 95th percentile."""
    from wtml.bench.coverage import interval_table

    n = 4000
    truth, sigma = rng.uniform(0, 1, n), np.full(n, 0.5)
    row = {"name": "gaussian", "kind": "test shard", "truth": truth,
           "err": rng.normal(0, 0.5, n), "groups": None, "sigma": sigma,
           "wide": np.full(n, 1.96), "raw": sigma * 2 / 3, "flagged": 0.0}
    rule = build(md.IntervalRecalibration, {"sigma": "sigma", "value": "distance",
                                            "by": "distance", "log_value": False,
                                            "stored": "std", "scales": [1.0],
                                            "widths": [1.96]})
    lines, rows = interval_table("toy", rule, [row])
    raw, fitted = rows
    assert raw["misses"] == 12 and raw["chance_misses"][1] <= 2
    assert fitted["misses"] <= fitted["chance_misses"][1] <= 2
    table = [line.strip("| ").split(" | ") for line in lines[-2:]]
    assert [t[:4] for t in table] == [["raw", "trained", "12", "12"],
                                      ["recalibrated", "trained", "12", str(fitted["misses"])]]
    assert table[0][-2] == "< 0.1 %" and float(table[1][-2].rstrip(" %")) > 5
    assert [t[-1] for t in table] == ["gaussian (12)", "none"]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(0.0, 1e300), st.sampled_from([0.0, np.inf])),
                min_size=1, max_size=120),
       st.floats(1e-320, 1e300))
def test_any_held_out_errors_give_a_recalibration_the_metadata_accepts(z, sigma):
    """Whatever the held-out errors (all exact, ties, 1e300, a σ so small that |err|/σ
    overflows): a scale and a width inside the metadata's bounds, and the export's rule
    builds; with at least MIN_PER_RANGE rows, through fit_scales too."""
    z = np.asarray(z)
    scale, width = level_widths(z)
    assert 1e-30 <= scale <= 1e30 and 1.0 <= width <= MAX_WIDTH
    rows = np.resize(np.where(np.isfinite(z), z, 1e300), 40)
    with np.errstate(over="ignore"):  # an error beyond 1e308 is not finite: left out
        err = rows * sigma
    edges, scales, widths = fit_scales(err, np.full(40, sigma), rows, 1)
    rule = build(md.IntervalRecalibration, {
        "sigma": "s", "value": "v", "by": "v", "log_value": False, "stored": "std",
        "edges": list(edges), "scales": list(scales), "widths": list(widths)})
    assert np.all(np.isfinite(rule.wide(rows)))


def test_the_coverage_bench_draws_its_fresh_records_from_the_seed_it_is_given(monkeypatch,
                                                                             capsys):
    """``--seed`` reaches the bench (another draw of every row), 2025 without it; a seed
    outside 0…2³²−1 is refused by name."""
    from wtml import cli
    from wtml.bench import coverage

    seen = []
    monkeypatch.setattr(coverage, "run_coverage",
                        lambda tasks, out, **kw: seen.append(kw["seed"]) or "report")
    assert cli.main(["bench", "coverage", "--only", "texture", "--seed", "2026"]) == 0
    assert cli.main(["bench", "coverage", "--only", "texture"]) == 0
    assert seen == [2026, 2025]
    with pytest.raises(SystemExit):
        cli.main(["bench", "coverage", "--seed", "-1"])
    assert "--seed" in capsys.readouterr().err


def test_rows_picks_the_named_rows_and_refuses_a_name_that_matches_none(monkeypatch):
    """``--rows`` reaches the bench, which keeps the tasks with a row whose name holds one
    of its texts (case-insensitive), each with its test shard first, and refuses, before
    measuring anything, a text that matches no row of any task, naming the rows there are."""
    from wtml import cli
    from wtml.bench import coverage
    from wtml.bench.coverage import RecordSet, pick_rows

    seen = []
    monkeypatch.setattr(coverage, "run_coverage",
                        lambda tasks, out, **kw: seen.append(kw["only_rows"]) or "report")
    assert cli.main(["bench", "coverage", "--only", "texture", "--rows", "in family",
                     "--rows", "LuGre"]) == 0
    assert cli.main(["bench", "coverage", "--only", "texture"]) == 0
    assert seen == [["in family", "LuGre"], None]

    def rows(*names):
        return [RecordSet(name, "kind", lambda: None) for name in names]

    sets = {"fluid": rows("test shard", "fresh records (in family)", "radius +1 %"),
            "texture": rows("test shard", "the trained scene (in family)",
                            "friction law lugre alone")}
    kept = pick_rows(sets, ["LUGRE"])
    assert {t: [s.name for s in r] for t, r in kept.items()} == {
        "texture": ["test shard", "friction law lugre alone"]}
    kept = pick_rows(sets, ["in family"])
    assert [s.name for s in kept["fluid"]] == ["test shard", "fresh records (in family)"]
    with pytest.raises(ValueError, match=r"--rows 'viscous' matches no row; the rows: "
                                         r"test shard; fresh records"):
        pick_rows(sets, ["lugre", "viscous"])


def test_the_coverage_bench_runs_two_tasks_and_their_named_rows(flow, radial_flow, tmp_path):
    """The bench end to end on the test suite's fluid and radial exports, a few records a
    row: every row of both tasks, its summary strict JSON (an empty cell null, not NaN), then
    with ``only_rows`` the test shards and the named rows alone (the loop's own names must
    not shadow the rows it was asked for)."""
    from wtml.bench.coverage import run_coverage

    fluid, ckpt = flow
    tasks = {"fluid": {"data": fluid / "data", "checkpoint": ckpt, "model": fluid / "export"},
             "radial": {"data": radial_flow / "data",  # its invalid contacts: another grid
                        "checkpoint": radial_flow / "runs/radial/checkpoints/last.ckpt",
                        "model": radial_flow / "export/radial"}}
    records = {"fluid": 12, "radial": 12, "onset": 2, "texture": 2, "independent": 0}
    report = run_coverage(tasks, tmp_path / "all", records=records, progress=lambda _: None)
    def no_constant(name):
        raise AssertionError(f"summary.json is not strict JSON: {name}")

    summary = json.loads((tmp_path / "all/summary.json").read_text(), parse_constant=no_constant)
    assert set(summary["tasks"]) == {"fluid", "radial"}
    every = {t: {r["name"] for r in e["intervals"][next(iter(e["intervals"]))]["rows"]}
             for t, e in summary["tasks"].items()}
    assert all(len(names) > 2 for names in every.values()) and "## radial" in report
    run_coverage(tasks, tmp_path / "some", records=records, only_rows=["Fresh records"],
                 progress=lambda _: None)
    some = json.loads((tmp_path / "some/summary.json").read_text())
    assert set(some["tasks"]) == {"fluid", "radial"}
    for task, entry in some["tasks"].items():
        names = {r["name"] for r in entry["intervals"][next(iter(entry["intervals"]))]["rows"]}
        assert names == {"test shard", "fresh records of the trained scene"}, task


def test_onset_records_of_one_device_are_judged_as_sharing_their_errors():
    """An onset row's records share the devices the scene drew for them (labelled by HUE(0),
    a device's own): 400 answers on 40 devices, each device's all covered or all missed at
    60 %, are a miss to the binomial count of 400 but too few to tell as the 40 they are
    worth; records of one device (the preset alone) carry no groups."""
    from wtml.bench.coverage import onset_truth

    rec = {"gap": np.arange(6.0), "hue0": np.array([2.0, 1.0, 2.0, 3.0, 1.0, 2.0])}
    np.testing.assert_array_equal(onset_truth(rec)["groups"], [1, 0, 1, 2, 0, 1])
    assert set(onset_truth({"gap": np.zeros(3), "hue0": np.full(3, 1.3)})) == {"gap"}
    device = np.repeat(np.arange(40), 10)
    hit = np.repeat(np.arange(40) < 24, 10).astype(float)  # 60 % of the devices
    covered = np.stack([hit, np.ones(400)], 1)
    groups = onset_truth({"gap": np.zeros(400), "hue0": 1.0 + device})["groups"]
    assert coverage_cell(covered)["verdict"][0] == "miss"
    alike = coverage_cell(covered, groups)
    assert alike["verdict"][0] == "?" and alike["n_effective"][0] == pytest.approx(40, rel=0.05)
