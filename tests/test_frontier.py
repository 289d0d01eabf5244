"""The frontier bench (issue 25 §2): budgets, the Pareto front, the quantisations' verdicts,
and one task's frontier measured on the small fluid flow's export."""

from __future__ import annotations

import numpy as np
import onnx
import pytest

from wtml.bench.fluid import frontier_problem
from wtml.bench.frontier import (
    Method,
    Problem,
    budget_rows,
    frontier,
    layer_nodes,
    measure,
    pareto,
    quantised_verdict,
    session_memory,
    side_by_side,
    speed_verdict,
)
from wtml.data import load_shards
from wtml.data.datamodule import split_shards
from wtml.runtime.predict import OnnxModel


def _row(name, value, latency, kind="decoder", verdict=None):
    return {"name": name, "kind": kind, "value": value, "low": value * 0.9,
            "high": value * 1.1, "latency_s": latency,
            "throughput": None if latency is None else 1 / latency,
            "verdict": verdict}


def _problem(higher=False):
    return Problem("t", "error", "%", higher, "sample", 1.0, (np.zeros((4, 2)),),
                   lambda pred: (0.0, 0.0, 0.0), "measurements", 8, (np.zeros((4, 2)),))


def test_each_budget_gets_the_most_accurate_method_that_fits():
    rows = [_row("fast", 30.0, 8e-6), _row("mid", 3.0, 60e-6), _row("slow", 2.5, 2e-3),
            _row("bound", 2.0, None, kind="bound"),
            _row("int8", 1.0, 5e-6, kind="quantised", verdict="dropped: less accurate")]
    best = {b["budget_s"]: b["name"] for b in budget_rows(_problem(), rows)}
    assert best == {10e-6: "fast", 100e-6: "mid", 1e-3: "mid", 10e-3: "slow"}
    rows[-1]["verdict"] = "kept: faster at equal accuracy"
    assert budget_rows(_problem(), rows)[0]["name"] == "int8"
    assert budget_rows(_problem(), [_row("slow", 2.5, 2e-3)])[0]["name"] is None
    # accuracy: higher is better
    acc = [_row("a", 80.0, 5e-6), _row("b", 90.0, 5e-6)]
    assert budget_rows(_problem(higher=True), acc)[0]["name"] == "b"


def test_the_speed_target_is_stated_with_what_meeting_it_costs():
    problem = _problem()
    problem.speed_target = (50e-6, 1e4)
    rows = [_row("decoder default ONNX", 3.0, 80e-6), _row("decoder tiny ONNX", 5.0, 20e-6),
            _row("decoder tiny int8 dynamic ONNX", 4.0, 10e-6, kind="quantised",
                 verdict="kept: faster at equal accuracy"),
            _row("decoder huge int8 static ONNX", 1.0, 10e-6, kind="quantised",
                 verdict="dropped: less accurate")]
    said = speed_verdict(problem, rows)
    assert "p50 80.0 µs at batch 1 (target ≤ 50.0 µs: MISSED)" in said
    assert "1.25e+04 samples/s" in said and "(target ≥ 1e+04: met)" in said
    # a dropped quantisation is no answer; the most accurate that meets both is
    assert said.endswith("decoder tiny int8 dynamic ONNX, 4 % against 3 % (p50 10.0 µs, "
                         "1e+05/s).")
    rows[0] = _row("decoder default ONNX", 3.0, 40e-6)
    assert "MISSED" not in speed_verdict(problem, rows)
    problem.speed_target = None
    assert speed_verdict(problem, rows) == ""


def test_the_pareto_front_has_no_dominated_method():
    rows = [_row("fast", 30.0, 8e-6), _row("dominated", 40.0, 50e-6), _row("mid", 3.0, 60e-6),
            _row("slow", 2.5, 2e-3)]
    assert pareto(_problem(), rows) == ["fast", "mid", "slow"]


def test_a_quantisation_is_kept_only_faster_at_equal_accuracy():
    base = _row("d", 3.0, 50e-6)
    assert quantised_verdict(_problem(), _row("q", 3.1, 40e-6), base).startswith("kept")
    assert "not faster" in quantised_verdict(_problem(), _row("q", 3.0, 60e-6) | {
        "throughput": 1 / 60e-6}, base)
    assert "less accurate" in quantised_verdict(_problem(), _row("q", 3.5, 40e-6), base)
    assert "not finite" in quantised_verdict(_problem(), _row("q", float("nan"), 40e-6), base)


def test_a_side_by_side_timing_decides_the_quantisation():
    """Timed side by side, the quantisation is faster only where three rounds in four were
    (its own latency row, measured after the decoder's, is not what decides)."""
    base = _row("d", 3.0, 50e-6)
    slower_alone = _row("q", 3.1, 60e-6) | {"throughput": 1 / 60e-6}
    paired = {"latency": (0.80, 0.78, 0.83), "batch": (1.0, 0.97, 1.02)}
    said = quantised_verdict(_problem(), slower_alone | {"paired": paired}, base)
    assert said.startswith("kept") and "side by side, time ×0.80 (0.78–0.83) at batch 1" in said
    shaky = {"latency": (0.90, 0.70, 1.10), "batch": (1.0, 0.97, 1.02)}
    assert "not faster" in quantised_verdict(_problem(), _row("q", 3.1, 40e-6) | {
        "paired": shaky}, base)
    slower_at_batch = {"latency": (0.80, 0.78, 0.83), "batch": (1.2, 1.1, 1.3)}
    assert "not faster" in quantised_verdict(_problem(), _row("q", 3.1, 40e-6) | {
        "paired": slower_at_batch}, base)


class _Ticking:
    """A predictor that advances a shared clock by a cost per row and a fixed cost per call
    (stands in for a method whose time the test knows)."""

    def __init__(self, clock: list[float], per_call: float, per_row: float) -> None:
        self.clock, self.per_call, self.per_row = clock, per_call, per_row

    def predict(self, x):
        self.clock[0] += self.per_call + self.per_row * len(x)
        return {}


def test_every_row_is_timed_side_by_side_with_the_default_decoder():
    """Each timed row gets its time over the default decoder's from alternating rounds; a
    quantisation of it keeps its verdict's pairing; a method whose throughput was its pass
    over the set is paired at batch 1 only; a bound is not timed."""
    now = [0.0]
    predictors = {"decoder default ONNX": _Ticking(now, 50e-6, 1e-6),
                  "classical": _Ticking(now, 25e-6, 0.5e-6),
                  "Bayes": _Ticking(now, 4e-3, 4e-3)}
    rows = [_row("decoder default ONNX", 3.0, 51e-6), _row("classical", 30.0, 26e-6),
            _row("Bayes", 2.4, 8e-3) | {"whole_pass": True}, _row("bound", 2.0, None),
            _row("decoder default float16 ONNX", 3.0, 40e-6, "quantised") | {
                "paired": {"latency": (0.9, 0.8, 1.0), "batch": (1.0, 0.9, 1.1)}}]
    for r in rows:
        r["note"] = ""
    side_by_side(_problem(), rows, predictors, "decoder default ONNX", 1.0,
                 progress=lambda text: None, clock=lambda: now[0])
    by = {r["name"]: r.get("side_by_side") for r in rows}
    assert by["decoder default ONNX"]["latency"] == (1.0, 1.0, 1.0)
    assert by["classical"]["latency"][0] == pytest.approx(25.5 / 51)
    assert by["classical"]["batch"][0] == pytest.approx((25e-6 + 4e-6) / (50e-6 + 8e-6))
    assert by["Bayes"]["latency"][0] == pytest.approx(8e-3 / 51e-6)
    assert by["Bayes"]["batch"] is None and by["bound"] is None
    assert by["decoder default float16 ONNX"]["latency"] == (0.9, 0.8, 1.0)


@pytest.fixture(scope="module")
def fluid_frontier(flow, tmp_path_factory):
    tmp, _ = flow
    out = tmp_path_factory.mktemp("frontier")
    problem = frontier_problem(tmp / "data", tmp / "export", threads=1, max_samples=200)
    result = frontier(problem, {"default": tmp / "export" / "model.onnx"}, out, threads=1,
                      latency_repeats=20, throughput_repeats=2, budget_s=0.2,
                      progress=lambda text: None)
    return tmp, out, problem, result


def test_the_fluid_frontier_measures_every_method_like_the_others(fluid_frontier):
    tmp, out, problem, result = fluid_frontier
    rows = {r["name"]: r for r in result["rows"]}
    kinds = {r["kind"] for r in rows.values()}
    assert {"decoder", "quantised", "classical", "reference", "bound"} <= kinds
    decoder = rows["decoder default ONNX"]
    # the decoder's row is its own predictions' median error, recomputed here
    ze, t = problem.inputs
    pred = OnnxModel(tmp / "export" / "model.onnx").predict(ze, t)
    eta = load_shards(tmp / "data", split_shards(4, 1, 1)["test"])["eta"][:200]
    assert decoder["value"] == pytest.approx(100 * np.median(np.abs(pred["eta"] / eta - 1)))
    assert decoder["low"] <= decoder["value"] <= decoder["high"]
    assert decoder["latency_s"] > 0 and decoder["throughput"] > 0
    assert decoder["size_bytes"] == (tmp / "export" / "model.onnx").stat().st_size
    assert rows["Cramér–Rao bound (no prior)"]["latency_s"] is None
    quantised = [r for r in rows.values() if r["kind"] == "quantised"]
    assert len(quantised) == 3
    assert all(r["verdict"].split(":")[0] in ("kept", "dropped") for r in quantised)
    assert all(np.isfinite(r["value"]) for r in quantised)  # each made, run and scored
    assert len(result["budgets"]) == 4 and (out / "fluid.png").stat().st_size > 0
    assert result["pareto"] and all(name in rows for name in result["pareto"])
    table = "\n".join(result["lines"])
    assert "| budget per sample |" in table and "decoder default ONNX" in table
    # every method with a cost is timed beside the decoder; the decoder is the unit
    timed = [r for r in rows.values() if r["latency_s"] is not None]
    assert decoder["side_by_side"]["latency"] == (1.0, 1.0, 1.0)
    assert all(r["side_by_side"]["latency"][1] <= r["side_by_side"]["latency"][0]
               <= r["side_by_side"]["latency"][2] for r in timed)
    assert "time, side by side (batch 1; batch" in table


def test_quantisation_keeps_the_metadata_and_leaves_the_gate_in_float32(fluid_frontier):
    tmp, out, problem, _ = fluid_frontier
    source = onnx.load(str(tmp / "export" / "model.onnx"))
    layers = layer_nodes(source)
    assert layers and not any("gate" in n for n in layers)
    made = out / "quantised" / "fluid" / "default" / "model.int8_dynamic.onnx"
    quantised = onnx.load(str(made))
    assert {p.key: p.value for p in quantised.metadata_props} == {
        p.key: p.value for p in source.metadata_props}
    # the int8 graph answers like the float one, to int8's precision
    ze, t = problem.inputs
    a = OnnxModel(tmp / "export" / "model.onnx").predict(ze, t)
    b = OnnxModel(made).predict(ze, t)
    assert np.median(np.abs(np.log(b["eta"] / a["eta"]))) < 0.05
    assert b["in_domain"].mean() >= a["in_domain"].mean() - 0.02


def test_the_session_memory_probe_sees_a_bigger_batch(flow):
    tmp, _ = flow
    graph = tmp / "export" / "model.onnx"
    n = OnnxModel(graph).frequency_hz.size
    one = (np.ones((1, n), complex), np.broadcast_to(np.eye(2), (1, n, 2, 2)).astype(complex))
    big = tuple(np.repeat(x, 20000, 0) for x in one)
    small_b, big_b = (session_memory(graph, "measurements", x, 1) for x in (one, big))
    assert 0 < small_b < big_b


def test_a_method_without_a_cost_is_a_bound():
    m = Method("bound", "bound", score=(1.0, 0.9, 1.1))
    row = measure(_problem(), m, threads=1, latency_repeats=1, throughput_repeats=1)
    assert row["latency_s"] is None and row["value"] == 1.0


def test_every_task_has_its_variants_and_a_bad_variants_file_is_refused(tmp_path):
    from wtml.bench.suite import VARIANTS, read_variants
    from wtml.tasks import TASKS

    for name in TASKS:
        variants = read_variants(VARIANTS, name)
        assert "default" in variants and len(variants) >= 2
    bad = tmp_path / "v.yaml"
    bad.write_text("fluid:\n  tiny: configs/nope.yaml\n")
    with pytest.raises(ValueError, match="fluid.tiny: no such config"):
        read_variants(bad, "fluid")
    with pytest.raises(ValueError, match="radial: must map each decoder variant"):
        read_variants(bad, "radial")
