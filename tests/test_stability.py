"""``wtml bench stability`` (wtml.bench.stability, wtml.bench.extremes): its verdicts, the
float32 device path against float64 on a small set, and its table built on a tiny export."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wtml.bench.extremes import (
    BLOWUP,
    Condition,
    Method,
    Suite,
    relative_difference,
    run_suite,
    verdict,
)
from wtml.bench.stability import run_stability


def test_relative_difference_is_relative_to_the_float64_answer_or_its_floor():
    high = np.array([1.0, -2.0, 0.0, 0.0, 1e-9, np.nan])
    low = np.array([1.001, -2.0, 0.0, 1e-3, 2e-9, 1.0])
    rel = relative_difference(low, high)
    assert rel[0] == pytest.approx(1e-3) and rel[1] == 0 and rel[2] == 0
    assert np.isinf(rel[3]) and rel[4] == pytest.approx(1.0) and np.isnan(rel[5])
    floored = relative_difference(low, high, floor=1e-6)
    assert floored[3] == pytest.approx(1e3) and floored[4] == pytest.approx(1e-3)


@pytest.mark.parametrize("kind,ratio,flagged,expect", [
    ("mid", 1.0, 0.0, "reference"),
    ("mid", 1.0, 0.5, "reference (false alarms)"),
    ("edge", 1.5, 0.0, "holds"),
    ("edge", 1.5, 0.5, "holds; false alarms"),
    ("edge", 4.0, 0.0, "loses ×4 inside the trained range"),
    ("beyond", 4.0, 0.95, "loses ×4; caught"),
    ("beyond", 4.0, 0.5, "loses ×4; NOT caught"),
    ("extreme", 30.0, None, "loses ×30; no flag"),
    ("extreme", float("nan"), 1.0, "answers 100 %, nothing to find; caught"),
])
def test_verdicts(kind, ratio, flagged, expect):
    assert verdict(kind, ratio, flagged) == expect


def test_answering_nothing_where_there_is_nothing_to_find_holds():
    assert verdict("extreme", float("nan"), 0.02, answered=0.0) == "holds: answers nothing"
    assert verdict("extreme", float("nan"), 0.0, answered=0.25) == (
        "answers 25 %, nothing to find; NOT caught")


def test_a_suite_scores_every_method_against_its_own_mid_domain_error():
    """A method whose error doubles beyond the range and a flag that fires there only."""
    def make(scale):
        return lambda n, rng: {"x": np.full(n, scale), "truth": np.zeros(n)}

    suite = Suite("toy", "error", "1", 1.0,
                  [Condition("beyond", "beyond", make(3.0)), Condition("middle", "mid",
                                                                      make(1.0))],
                  [Method("flagged", lambda r: {"y": r["x"], "in_domain": r["x"] < 2}),
                   Method("float64", lambda r: {"y": r["x"]})],
                  lambda rec, pred: float(np.mean(np.abs(pred["y"] - rec["truth"]))),
                  lambda rec, pred: "", (("flagged", "float64", (("y", 0.0),)),))
    out = run_suite(suite, 4, 0)
    rows = {(r["condition"], r["method"]): r for r in out["rows"]}
    assert [r["condition"] for r in out["rows"]][:2] == ["beyond", "beyond"]  # the suite's order
    assert rows["beyond", "flagged"]["ratio"] == pytest.approx(3.0)
    assert rows["beyond", "flagged"]["verdict"] == "loses ×3; caught"
    assert rows["beyond", "float64"]["verdict"] == "loses ×3; no flag"
    assert rows["middle", "flagged"]["flagged"] == 0.0
    assert all(r["max"] == 0.0 for r in out["float32"])
    with pytest.raises(ValueError, match="exactly one condition of kind 'mid'"):
        Suite("toy", "e", "1", 1.0, [Condition("a", "edge", make(1.0))], [], len, len)
    with pytest.raises(ValueError, match="kind: one of"):
        Condition("a", "middle", make(1.0))


@pytest.fixture(scope="module")
def fluid_stability(flow, tmp_path_factory):
    """The fluid suite of the tiny export (tests/conftest.py ``flow``), 8 records a condition;
    the radial, onset and texture exports are absent."""
    models = tmp_path_factory.mktemp("models")
    (models / "fluid").symlink_to(flow[0] / "export")
    out = models / "out"
    report = run_stability(models, out, records=8, seed=3)
    return report, json.loads((out / "summary.json").read_text())


def test_the_table_names_every_condition_and_method_and_the_missing_exports(fluid_stability):
    report, summary = fluid_stability
    rows = summary["tasks"]["fluid"]["rows"]
    conditions = {r["condition"] for r in rows}
    methods = {r["method"] for r in rows}
    assert len(rows) == len(conditions) * len(methods) == 7 * 4
    assert len([line for line in report.splitlines() if line.startswith("| fluid |")]) \
        == len(rows) + 2 * len(conditions)  # and two float32 rows (η, ρ) per condition
    assert "Skipped: radial (no export at" in report and "onset" in summary["skipped"][1]
    mid = [r for r in rows if r["kind"] == "mid"]
    assert all(r["ratio"] == 1.0 and r["verdict"].startswith("reference") for r in mid)


def test_the_extremes_are_caught_by_the_decoders_flag(fluid_stability):
    """The sphere in air (a free tip) and held (clamped) are far outside the trained loads:
    the decoder's graph flags every record; the numpy path has no flag to raise."""
    rows = fluid_stability[1]["tasks"]["fluid"]["rows"]
    for r in rows:
        if r["kind"] == "extreme":
            if r["method"] == "decoder ONNX":
                assert r["flagged"] == 1.0 and r["verdict"].endswith("caught"), r
            if "numpy" in r["method"]:
                assert r["flagged"] is None and r["verdict"].endswith("no flag"), r


def test_float32_closed_form_agrees_mid_domain_and_loses_digits_at_a_free_tip(fluid_stability):
    """The classical graph in float32 against numpy in float64 on the same Ze: mid-domain a
    few float32 eps (the band least squares is well conditioned there); with the sphere in
    air Zm is ~1e-4 of the transducer's own impedance and its small Stokes term is a
    difference of large numbers, so the relative difference of η grows by orders."""
    f32 = {(r["condition"], r["output"]): r for r in fluid_stability[1]["tasks"]["fluid"]
           ["float32"]}
    mid = next(c for c, o in f32 if "middle decade" in c)
    air = next(c for c, o in f32 if "air" in c)
    assert f32[mid, "eta"]["max"] < 1e-3 and f32[mid, "rho"]["max"] < 1e-4
    assert f32[air, "eta"]["median"] > 10 * f32[mid, "eta"]["median"]
    assert f32[mid, "eta"]["max"] < BLOWUP


def test_a_fluid_scene_simulates_a_fluid_outside_its_prior():
    """``properties`` fixes η and ρ (air, here) with the same nuisance as the prior's draws: the
    Ze is that of the Stokes sphere in that fluid through the same calibrated T and noise."""
    from wtml.physics import ze_from_zm
    from wtml.physics.loads import stokes_sphere
    from wtml.scenes.fluid import FluidScene, NoiseSpec, NuisanceSpec

    scene = FluidScene(noise=NoiseSpec(ze_relative=0.0),
                       nuisance=NuisanceSpec(calibration_error=0.0))
    air = scene.simulate(5, np.random.default_rng(1), properties=(1.81e-5, 1.2))
    drawn = scene.simulate(5, np.random.default_rng(1))
    assert np.all(air["eta"] == 1.81e-5) and np.all(np.isnan(air["volume_fraction"]))
    np.testing.assert_array_equal(air["sphere_radius"], drawn["sphere_radius"])
    zm = stokes_sphere(1.81e-5, 1.2, scene.sphere.radius, scene.excitation.omega)
    np.testing.assert_allclose(air["ze"], ze_from_zm(air["t"], zm), rtol=1e-12)
    assert np.max(np.abs(air["ze"] / drawn["ze"] - 1)) > 1e-3  # air is not glycerol-water
    with pytest.raises(ValueError, match=r"properties eta must be in \(0, inf\)"):
        scene.simulate(2, np.random.default_rng(1), properties=(-1.0, 1000.0))


def test_texture_conditions_carry_t_at_the_exports_calibration_frequencies(texture_export,
                                                                           monkeypatch):
    """Every texture condition narrows a range of the trained scene, and the whisking range
    moves the scene's own calibration frequencies: each must ask for T at the graph's
    (its metadata's ``calibration_hz``), or the decoder reads T at the wrong frequencies."""
    from wtml.bench.stability_suites import SUITES
    from wtml.runtime.predict import load_export
    from wtml.scenes.texture import TextureScene

    asked = []

    def simulate(self, n, rng, **kwargs):
        asked.append((self.drive.whisk_hz, kwargs.get("calibration_hz")))
        return {}

    monkeypatch.setattr(TextureScene, "simulate", simulate)
    suite = SUITES["texture"](texture_export["model"], 1)
    for condition in suite.conditions:
        condition.make(1, np.random.default_rng(0))
    want = np.array(load_export(texture_export["model"])[0].meta.calibration_hz)
    assert len(asked) == len(suite.conditions) >= 7
    assert any(hz[1] - hz[0] < 1.0 for hz, _ in asked)  # narrowed: its own frequencies moved
    for _, freq in asked:
        np.testing.assert_array_equal(freq, want)
