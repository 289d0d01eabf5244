"""The fluid flow end to end on a tiny dataset: train from the config (LightningCLI), resume,
export, ONNX parity with torch and numpy, and ``wtml predict`` on every input format."""

import csv
import dataclasses
import json
import os
import re
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from conftest import FLUID_SMALL, train_args

from wtml.baselines import ClassicalFluid
from wtml.bench.bounds import fluid_crlb
from wtml.bench.fluid import run_bench
from wtml.cli import main
from wtml.data import load_shards
from wtml.decoders.checkpoint import load_decoder, read_checkpoint
from wtml.decoders.domain import Gated
from wtml.decoders.fluid import TorchFluid, load_fluid_net
from wtml.decoders.layers import SignedLogZm, ZmFromZe
from wtml.exporters.common import ClassicalFluidNet
from wtml.physics import ze_from_zm, zm_from_ze
from wtml.physics.fluids import glycerol_water
from wtml.physics.loads import stokes_sphere
from wtml.physics.twoport import flat_parts
from wtml.runtime.predict import InputError, OnnxModel, predict_file
from wtml.scenes import FluidScene, to_dict
from wtml.schema import SceneError, build
from wtml.signals import complex_noise, sample_times, tone
from wtml.training import cli_main

ROOT = Path(__file__).resolve().parents[1]
SCENE = FLUID_SMALL  # the flow fixture's scene (conftest.py)
SPREAD = build(FluidScene, {"spread": {"k": 0.03, "m": 0.01, "c": 0.25, "phi": 0.03,
                                       "c0": 0.03, "tan_delta": 0.25, "sphere_radius": 0.01}})


def _tensors(*arrays):
    return tuple(torch.tensor(np.asarray(a), dtype=torch.float32) for a in arrays)


def test_zero_spread_reproduces_the_preset_records_bit_for_bit():
    """Without a spread the scene draws nothing more: today's algorithm (one T for every
    record), written out here, gives the same records bit for bit, and each record's ``t`` is
    the preset's T."""
    n, scene = 500, build(FluidScene, {})
    got = scene.simulate(n, np.random.default_rng(7))
    rng = np.random.default_rng(7)
    cv, temp = rng.uniform(0.0, 1.0, n), rng.uniform(15.0, 40.0, n)
    eta, rho = glycerol_water(cv, temp)
    s = 0.01 / np.sqrt(2)
    alpha = s * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    beta = s * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    zm = stokes_sphere(eta[:, None], rho[:, None], scene.sphere.radius, scene.excitation.omega)
    zm = (1 + alpha[:, None]) * zm + beta[:, None] * scene.reference_zm()
    ze = complex_noise(ze_from_zm(scene.calibrated_t(), zm), 1e-4, rng)
    for key, ref in (("ze", ze), ("eta", eta), ("rho", rho), ("cal_gain", alpha)):
        assert np.array_equal(got[key], ref), key
    assert np.array_equal(got["t"], np.broadcast_to(scene.calibrated_t(), got["t"].shape))


def test_device_spread_draws_each_device_within_its_stated_bounds():
    """Each record has its own device: its T maps its Ze back to its own sphere's Stokes load
    exactly (no noise, no calibration error), the radius stays in ±1 %, and the lumped
    parameters seen in T (t11 = 1/φ, t21/t11 = jω C0 (1 - j tanδ)) in their half-widths."""
    clean = build(FluidScene, {"spread": to_dict(SPREAD.spread), "noise": {"ze_relative": 0.0},
                               "nuisance": {"calibration_error": 0.0}})
    d = clean.simulate(400, np.random.default_rng(3))
    omega = clean.excitation.omega
    zm = stokes_sphere(d["eta"][:, None], d["rho"][:, None], d["sphere_radius"][:, None], omega)
    np.testing.assert_allclose(zm_from_ze(d["t"], d["ze"]), zm, rtol=1e-7)
    ratio = d["sphere_radius"] / clean.sphere.radius - 1
    assert np.abs(ratio).max() <= 0.01 and np.abs(ratio).max() > 0.009
    base = clean.transducer.build()
    phi = 1 / d["t"][:, 0, 0, 0].real
    assert np.abs(phi / base.phi - 1).max() <= 0.03 and np.std(phi / base.phi) > 0.01
    c0 = (d["t"][:, :, 1, 0] / d["t"][:, :, 0, 0]).imag / omega
    assert np.abs(c0 / base.c0 - 1).max() <= 0.03 + 1e-12
    with pytest.raises(SceneError, match=r"spread.sphere_radius: must be in \[0, 0.2\]"):
        build(FluidScene, {"spread": {"sphere_radius": 0.5}})


def test_an_unmeasured_radius_is_a_fluid_with_scaled_properties():
    """The Stokes load depends on R only through ηR, R² sqrt(ηρ) and R³ρ, so a sphere of
    radius R(1 + ε) in (η, ρ) is exactly a sphere of radius R in (η(1 + ε), ρ(1 + ε)³): the
    classical path with the nominal radius reads those on clean records, to rounding. (Only a
    prior over (η, ρ) can tell the radius's share apart: the bench's device-spread table.)"""
    clean = build(FluidScene, {"spread": {"sphere_radius": 0.01}, "noise": {"ze_relative": 0.0},
                               "nuisance": {"calibration_error": 0.0}})
    d = clean.simulate(300, np.random.default_rng(11))
    eps = d["sphere_radius"] / clean.sphere.radius - 1
    assert np.abs(eps).max() > 0.009
    pred = ClassicalFluid(clean.excitation.omega, clean.sphere.radius).predict(d["ze"], d["t"])
    np.testing.assert_allclose(pred["eta"], d["eta"] * (1 + eps), rtol=1e-7)
    np.testing.assert_allclose(pred["rho"], d["rho"] * (1 + eps) ** 3, rtol=1e-7)


def test_the_unmeasured_sphere_scene_is_the_default_with_issue_21s_spread():
    """``configs/scenes/fluid_radius.yaml`` differs from the main job's fluid scene only by
    its name and the sphere's radius, unmeasured in ±1 %: its spread is issue 21's whole
    (the held-out rows of the fluid bench and ``wtml bench coverage``), so a decoder trained
    on it is judged on its own prior there."""
    from wtml.bench.fluid import REFERENCE_SPREAD
    from wtml.scenes import load_scene

    default = load_scene(ROOT / "configs/scenes/fluid.yaml")
    radius = load_scene(ROOT / "configs/scenes/fluid_radius.yaml")
    assert radius.spread == REFERENCE_SPREAD and default.spread.sphere_radius == 0.0
    assert radius.name == "fluid_radius"
    assert dataclasses.replace(radius, name=default.name, spread=default.spread) == default


def test_the_eta_range_ends_where_the_prior_does_and_hot_water_is_beyond_it():
    """A decoder's η counts as in domain only a little beyond the prior's range (a factor
    1.084): the prior's lowest η (water at its highest temperature)
    and 7 % below it (the decoder's median error on the prior's lowest decade) are inside,
    while water at 60 °C (0.47 mPa·s), below the prior, and 0.58 mPa·s (the main job's
    decoder's 90th-percentile answer to water at 60–95 °C) are outside. With the 5 % margin
    of the other ranges (a factor 1.5) both were inside, and 41 % of those records passed."""
    from wtml.scenes import load_scene

    scene = load_scene(ROOT / "configs/scenes/fluid.yaml")
    r = scene.output_ranges()["eta"]
    lo, hi = r.widened()
    coolest_water = glycerol_water(0.0, scene.fluid.temperature_c[1])[0]
    assert r.low == pytest.approx(float(coolest_water), rel=1e-12)
    assert lo < 0.93 * r.low and hi > 1.07 * r.high
    assert float(glycerol_water(0.0, 60.0)[0]) < 0.58e-3 < lo
    # the margin is in decades: a narrower prior (water with 0-30 % glycerol) keeps the factor
    narrow = dataclasses.replace(scene, fluid=dataclasses.replace(scene.fluid,
                                                                  volume_fraction=(0.0, 0.3)))
    n = narrow.output_ranges()["eta"]
    assert n.widened()[0] / n.low == pytest.approx(lo / r.low, rel=1e-9)


def test_a_checkpoint_exports_the_ranges_this_version_states(flow):
    """The outputs' trained ranges (the scene's, with this version's margins) replace those a
    checkpoint saved: a checkpoint from before a margin changed exports what its metadata
    states, not the old range."""
    from wtml.scenes import scene_from_dict

    path = flow[1]
    module = load_decoder(path)
    eta = scene_from_dict(module.scene).output_ranges()["eta"].widened()
    want = (module.gate.low.clone(), module.gate.high.clone())
    assert (float(want[0][0]), float(want[1][0])) == pytest.approx(eta, rel=1e-6)
    checkpoint = read_checkpoint(path)
    checkpoint["state_dict"]["gate.low"] = want[0] / 1.5  # as saved under another margin
    checkpoint["state_dict"]["gate.high"] = want[1] * 1.5
    module.on_load_checkpoint(checkpoint)
    module.load_state_dict(checkpoint["state_dict"])
    torch.testing.assert_close(module.gate.low, want[0], rtol=0, atol=0)
    torch.testing.assert_close(module.gate.high, want[1], rtol=0, atol=0)


def test_zm_layer_with_the_nominal_t_reproduces_the_constant_t_graph():
    """Parity with the graph before T was an input: there the constants of the Möbius map
    (c = t11/t21, A = -t22/t21, B = -det T/t21²) were computed once in float64 and stored in
    float32; here the quotient form takes the float32 T. The two agree to what the old graph
    loses to float32 (2e-6 of the largest |Zm|, 1/50 of the noise)."""
    t = SCENE.calibrated_t()
    ze = SCENE.simulate(256, np.random.default_rng(0))["ze"]
    t11, t12, t21, t22 = t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1]
    c, a, b = (np.complex64(v)
               for v in (t11 / t21, -t22 / t21, -(t11 * t22 - t12 * t21) / t21**2))
    old = a + b / (ze.astype(np.complex64) - c)  # the constant-T graph, float32
    every = np.broadcast_to(t, (256, *t.shape))
    zr, zi = ZmFromZe()(*_tensors(ze.real, ze.imag, *flat_parts(every)))
    new = zr.numpy() + 1j * zi.numpy()
    ref = zm_from_ze(t, ze)  # float64
    lost = np.abs(old - ref).max()  # what the old float32 graph loses (2.1e-6 of max |Zm|)
    assert lost <= 1e-5 * np.abs(ref).max()
    # the T input itself is rounded to float32: the new graph loses 1.7x as much (measured
    # 3.5e-6 against 2.1e-6 of the largest |Zm|), both far below the noise
    assert np.abs(new - old).max() <= 3 * lost and np.abs(new - ref).max() <= 3 * lost


# resuming into the run's own checkpoint folder is the point here; lightning remarks on it
@pytest.mark.filterwarnings("ignore:Checkpoint directory .* exists and is not empty")
def test_interrupted_training_resumes(flow):
    tmp, _ = flow
    ckpt = tmp / "runs/fluid/checkpoints/last.ckpt"
    saved = read_checkpoint(ckpt)
    assert saved["epoch"] == 1
    cwd = os.getcwd()
    os.chdir(tmp)
    try:
        cli = cli_main(train_args(tmp, "--ckpt_path", str(ckpt)))
    finally:
        os.chdir(cwd)
    assert cli.trainer.current_epoch == 3  # epochs 2 only, then done: continued, not restarted
    assert cli.trainer.global_step == saved["global_step"] + saved["global_step"] // 2


def test_exported_models_are_valid_and_carry_metadata(flow):
    tmp, _ = flow
    for name, kind in (("model.onnx", "decoder"), ("classical.onnx", "classical")):
        model = onnx.load(str(tmp / "export" / name))
        onnx.checker.check_model(model, full_check=True)
        meta = {p.key: p.value for p in model.metadata_props}
        assert meta["kind"] == kind and meta["task"] == "fluid" and len(meta["scene_hash"]) == 64
        assert '"eta": "Pa*s"' in meta["units"] and meta["wtml_version"]
        assert model.graph.input[0].type.tensor_type.shape.dim[0].dim_param  # dynamic batch


def test_decoder_onnx_matches_torch(flow):
    """Same float32 graph, different kernels: agreement to 1e-5 relative (a few float32 ulps
    through the network) at batch 1 and at a large batch. The exported graph computes Zm once
    for the net and its domain gate; the gate's score matches the gate run on its own."""
    tmp, ckpt = flow
    module = load_decoder(ckpt)
    graph = Gated(module.net, module.gate).eval()
    assert graph.shared and module.gate.features is module.net.features
    net, _ = load_fluid_net(str(ckpt))
    shard = load_shards(tmp / "data", [3])
    ze, t = shard["ze"], shard["t"]
    torch_pred = TorchFluid(net).predict(ze, t)
    onnx_pred = OnnxModel(tmp / "export/model.onnx").predict(ze, t)
    for k in ("eta", "rho"):
        np.testing.assert_allclose(onnx_pred[k], torch_pred[k], rtol=1e-5)
    with torch.no_grad():
        score = module.gate(*_tensors(ze.real, ze.imag, *flat_parts(t))).numpy()
    # a float32 quadratic form of standardised features: kernel differences reach 1.6e-4
    np.testing.assert_allclose(onnx_pred["domain_score"], score, rtol=1e-3)
    one = OnnxModel(tmp / "export/model.onnx").predict(ze[:1], t[:1])
    np.testing.assert_allclose(one["eta"], torch_pred["eta"][:1], rtol=1e-5)
    # devices of the spread (each its own T, which this zero-spread export flags)
    other = SPREAD.simulate(64, np.random.default_rng(1))
    torch_pred = TorchFluid(net).predict(other["ze"], other["t"])
    onnx_pred = OnnxModel(tmp / "export/model.onnx").predict(other["ze"], other["t"])
    for k in ("eta", "rho"):
        np.testing.assert_allclose(onnx_pred[k], torch_pred[k], rtol=1e-5)
    assert onnx_pred["in_domain"].mean() < 0.05


def test_classical_onnx_float32_matches_numpy_float64(flow):
    """The float32 graph differs from float64 numpy by what float32 loses in Ze -> Zm
    (test_float32.py), carried through the band least squares, which is linear:
    |Δη| <= Σ_k |P_ηk| |ΔZm_k| (P its pseudo-inverse), plus the float32 rounding of that
    sum. The ONNX graph and the same graph in torch agree to float32 kernel differences."""
    tmp, _ = flow
    shard = load_shards(tmp / "data", [3])
    ze, t = shard["ze"], shard["t"]
    numpy_path = ClassicalFluid(SCENE.excitation.omega, SCENE.sphere.radius)
    ref = numpy_path.predict(ze, t)
    net = ClassicalFluidNet(SCENE.excitation.omega, SCENE.sphere.radius)
    inputs = _tensors(ze.real, ze.imag, *flat_parts(t))
    zr, zi = net.zm(*inputs)
    zm64 = numpy_path.zm(ze, t)
    dzm = np.concatenate([np.abs(zr.double().numpy() - zm64.real),
                          np.abs(zi.double().numpy() - zm64.imag)], -1)
    x = np.concatenate([np.abs(zm64.real), np.abs(zm64.imag)], -1)
    eps32 = float(np.finfo(np.float32).eps)
    got = dict(zip(("eta", "rho"), (v.double().numpy() for v in net(*inputs)), strict=True))
    for row, key in enumerate(("eta", "rho")):
        p = np.abs(numpy_path.pinv[row])
        bound = 1.5 * (dzm @ p) + 64 * eps32 * (x @ p)
        assert np.all(np.abs(got[key] - ref[key]) <= bound), key
    onnx_pred = OnnxModel(tmp / "export/classical.onnx").predict(ze, t)
    for key in ("eta", "rho"):
        scale = np.abs(ref[key]).max()
        np.testing.assert_allclose(onnx_pred[key], got[key], rtol=1e-5, atol=1e-6 * scale)


def test_zm_layer_matches_numpy():
    d = SPREAD.simulate(64, np.random.default_rng(0))
    ze, t = d["ze"], d["t"]
    zr, zi = ZmFromZe()(*_tensors(ze.real, ze.imag, *flat_parts(t)))
    ref = zm_from_ze(t, ze)
    np.testing.assert_allclose(zr.numpy() + 1j * zi.numpy(), ref, rtol=2e-5 * 10,
                               atol=1e-5 * np.abs(ref).max())
    eta, rho = ClassicalFluidNet(SCENE.excitation.omega, SCENE.sphere.radius)(
        *_tensors(ze.real, ze.imag, *flat_parts(t)))
    assert eta.shape == rho.shape == (64,)


@pytest.mark.parametrize("n_freq", [31, 4])
def test_signed_log_features_are_zm_and_the_device_elements_they_name(n_freq):
    """The feature layer: ``sign(x) log(1 + |x|)`` of Zm / z_scale (Re at every frequency,
    then Im), then the six device elements its docstring names (Re t11, Re t12, Im t12 at the
    first frequency, Im t12 at the last, Re and Im t21 at the middle one), at an odd and an
    even grid."""
    d = SPREAD.simulate(16, np.random.default_rng(1))
    ze, t = d["ze"][:, :n_freq], d["t"][:, :n_freq]
    layer = SignedLogZm(50.0, n_freq)
    x = layer(*_tensors(ze.real, ze.imag, *flat_parts(t))).double().numpy()
    zm = zm_from_ze(t, ze) / 50.0
    for k, part in enumerate((zm.real, zm.imag)):
        np.testing.assert_allclose(x[:, k * n_freq:(k + 1) * n_freq],
                                   np.sign(part) * np.log1p(np.abs(part)), rtol=1e-4, atol=1e-6)
    mid, last = n_freq // 2, n_freq - 1
    want = np.stack([t[:, 0, 0, 0].real, t[:, 0, 0, 1].real, t[:, mid, 1, 0].real,
                     t[:, 0, 0, 1].imag, t[:, last, 0, 1].imag, t[:, mid, 1, 0].imag], -1)
    np.testing.assert_allclose(x[:, 2 * n_freq:], want, rtol=1e-6)


def _write_csv(path, freq, ze):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["sample", "frequency_hz", "ze_real", "ze_imag"])
        for s, row in enumerate(ze):
            for f, z in zip(freq, row, strict=True):
                w.writerow([s, repr(float(f)), repr(float(z.real)), repr(float(z.imag))])


def test_predict_every_input_format_agrees(flow, tmp_path, capsys):
    tmp, _ = flow
    freq = SCENE.excitation.frequency_hz
    ze = load_shards(tmp / "data", [3])["ze"][:2]
    cal = tmp_path / "cal.npz"
    np.savez(cal, frequency_hz=freq, t=SCENE.calibrated_t())
    _write_csv(tmp_path / "m.csv", freq, ze)
    np.savez(tmp_path / "m.npz", frequency_hz=freq, ze=ze)
    # raw signals: a stepped sine, 40 periods per step at 20 kHz, E = 3 V, I = E/Ze
    fs = 20_000.0
    t = sample_times(0.4, fs)
    e = np.stack([[tone(t, f, 3.0) for f in freq]] * 2)
    i = np.stack([[tone(t, f, abs(3.0 / z), np.angle(3.0 / z))
                   for f, z in zip(freq, row, strict=True)] for row in ze])
    np.savez(tmp_path / "raw.npz", frequency_hz=freq, e=e, i=i, sample_rate_hz=fs)
    rows = {name: predict_file(tmp / "export", tmp_path / name, calibration=cal)
            for name in ("m.csv", "m.npz", "raw.npz")}
    for name in ("m.npz", "raw.npz"):
        for a, b in zip(rows["m.csv"], rows[name], strict=True):
            assert a.keys() == b.keys()
            for key in a:
                if isinstance(a[key], float):
                    assert a[key] == pytest.approx(b[key], rel=1e-5), (name, key)
                else:  # sample, in_domain, flags
                    assert a[key] == b[key], (name, key)
    model = str(tmp / "export")
    assert main(["predict", "--model", model, "--input", str(tmp_path / "m.csv"),
                 "--calibration", str(cal)]) == 0
    assert "eta_decoder (Pa*s)" in capsys.readouterr().out
    # one T per measurement gives the same rows as one T for all
    np.savez(tmp_path / "cal2.npz", frequency_hz=freq,
             t=np.stack([SCENE.calibrated_t()] * 2))
    assert predict_file(tmp / "export", tmp_path / "m.csv", calibration=tmp_path / "cal2.npz") \
        == rows["m.csv"]


def test_predict_needs_the_calibration(flow, tmp_path, capsys):
    """A fluid export without --calibration, or with a wrong one, is a clear error, never a
    silent default; the export says what it needs."""
    tmp, _ = flow
    freq = SCENE.excitation.frequency_hz
    np.savez(tmp_path / "m.npz", frequency_hz=freq, ze=load_shards(tmp / "data", [3])["ze"][:2])
    with pytest.raises(InputError, match=r"this fluid export needs --calibration: the device's "
                                         r"calibrated T at 90, 91, 92, \.\.\. 120 Hz"):
        predict_file(tmp / "export", tmp_path / "m.npz")
    assert main(["predict", "--model", str(tmp / "export"), "--input",
                 str(tmp_path / "m.npz")]) == 2
    assert "--calibration" in capsys.readouterr().err
    np.savez(tmp_path / "grid.npz", frequency_hz=freq + 1, t=SCENE.calibrated_t())
    with pytest.raises(InputError, match="calibration grid 91-121 Hz"):
        predict_file(tmp / "export", tmp_path / "m.npz", calibration=tmp_path / "grid.npz")
    np.savez(tmp_path / "shape.npz", frequency_hz=freq, t=SCENE.calibrated_t()[:, 0])
    with pytest.raises(InputError, match=r"t must have shape \(n_freq=31, 2, 2\)"):
        predict_file(tmp / "export", tmp_path / "m.npz", calibration=tmp_path / "shape.npz")
    np.savez(tmp_path / "keys.npz", frequency_hz=freq, T=SCENE.calibrated_t())
    with pytest.raises(InputError, match="needs 'frequency_hz' and 't'"):
        predict_file(tmp / "export", tmp_path / "m.npz", calibration=tmp_path / "keys.npz")
    for name in ("model.onnx", "classical.onnx"):
        meta = {p.key: p.value for p in onnx.load(str(tmp / "export" / name)).metadata_props}
        assert "calibration" in json.loads(meta["references"])
        assert json.loads(meta["inputs"]) == ["ze_re", "ze_im", "t_re", "t_im"]


def test_predict_refuses_bad_input(flow, tmp_path):
    tmp, _ = flow
    freq = SCENE.excitation.frequency_hz
    ze = load_shards(tmp / "data", [3])["ze"][:1]
    cal = tmp_path / "cal.npz"
    np.savez(cal, frequency_hz=freq, t=SCENE.calibrated_t())
    np.savez(tmp_path / "grid.npz", frequency_hz=freq + 1.0, ze=ze)
    with pytest.raises(InputError, match=r"frequency grid 91-121 Hz \(31 points\) is not the "
                                         r"model's 90-120 Hz"):
        predict_file(tmp / "export", tmp_path / "grid.npz", calibration=cal)
    bad = ze.copy()
    bad[0, 4] = np.nan
    np.savez(tmp_path / "nan.npz", frequency_hz=freq, ze=bad)
    with pytest.raises(InputError, match=r"NaN or inf at sample 0, 94 Hz"):
        predict_file(tmp / "export", tmp_path / "nan.npz", calibration=cal)
    np.savez(tmp_path / "shape.npz", frequency_hz=freq, ze=ze[:, :30])
    with pytest.raises(InputError, match=r"shape \(n, n_freq=31\)"):
        predict_file(tmp / "export", tmp_path / "shape.npz", calibration=cal)
    np.savez(tmp_path / "keys.npz", frequency_hz=freq, z=ze)
    with pytest.raises(InputError, match="needs 'ze'"):
        predict_file(tmp / "export", tmp_path / "keys.npz", calibration=cal)
    (tmp_path / "x.txt").write_text("1")
    model = str(tmp / "export")
    assert main(["predict", "--model", model, "--input", str(tmp_path / "x.txt")]) == 2


def test_bench_reports_every_method(flow, tmp_path):
    tmp, ckpt = flow
    report = run_bench(tmp / "data", ckpt, tmp / "export", tmp_path, latency_repeats=5,
                       throughput_repeats=1, device_records=40)
    for name in ("thesis closed form numpy", "thesis closed form ONNX", "decoder torch",
                 "decoder ONNX", "Bayes posterior mean", "Cramér–Rao bound (no prior)"):
        assert f"| {name}" in report
    exact = re.search(r"max relative error η (\S+), ρ (\S+)\.\s", report)
    assert float(exact[1].rstrip(",")) <= 1e-9 and float(exact[2]) <= 1e-9
    assert (tmp_path / "report.md").read_text() == report
    for row in ("nominal device", "trained spread", "issue 21 spread", "k ±3 % only",
                "sphere_radius ±1 % only"):
        assert f"| {row} |" in report
    summary = json.loads((tmp_path / "summary.json").read_text())
    timing = summary["timing"]  # how the times were taken: threads, the machine's other work
    assert timing["threads"] == 2 and timing["cores"] >= 1
    assert 0 <= timing["busy_elsewhere"] <= 1
    assert "cores busy" in report.split("| method |")[0]
    rows = {r["device"]: r for r in summary["device_spread"]}
    assert len(rows) == 3 + 7  # nominal, trained, issue 21's, and each parameter alone
    for r in rows.values():
        names = [m["name"] for m in r["methods"]]
        assert names == ["decoder ONNX", "thesis closed form ONNX", "Bayes posterior mean"]
        for m in r["methods"]:  # (this decoder: 3 epochs of a 32-wide net, far off)
            assert 0 < m["eta_median"] < np.inf and 0 < m["rho_median"] < np.inf
        assert all(0 <= m["flagged"] <= 1 for m in r["methods"][:2])
        assert r["methods"][2]["flagged"] is None
    assert (tmp_path / "error_vs_latency.png").stat().st_size > 10_000


def test_crlb_scales_with_noise_and_grows_with_calibration_error():
    eta, rho = np.array([1e-3, 1e-1]), np.array([1000.0, 1200.0])
    quiet = fluid_crlb(build(FluidScene, {"nuisance": {"calibration_error": 0.0}}), eta, rho)
    loud = fluid_crlb(build(FluidScene, {"nuisance": {"calibration_error": 0.0},
                                         "noise": {"ze_relative": 2e-4}}), eta, rho)
    np.testing.assert_allclose(loud["eta"], 2 * quiet["eta"], rtol=1e-3)  # linear in σ
    cal = fluid_crlb(build(FluidScene, {}), eta, rho)
    assert np.all(cal["eta"] > 10 * quiet["eta"]) and np.all(cal["rho"] > quiet["rho"])


def test_a_session_s_first_run_is_one_row(flow, monkeypatch):
    """``OnnxModel`` runs its graph once on one row of zeros when it opens it, before any
    other call (a session whose first run was a large batch stays ~20 % slower at batch 1:
    docs/frontier.md, "Where batch 1's time goes"); a graph with a second dynamic axis is not
    run."""
    from types import SimpleNamespace

    from wtml.runtime import predict

    runs = []

    class Recording(ort.InferenceSession):
        def run(self, names, feed, *args):
            runs.append({k: np.array(v) for k, v in feed.items()})
            return super().run(names, feed, *args)

    monkeypatch.setattr(predict.ort, "InferenceSession", Recording)
    tmp, _ = flow
    model = OnnxModel(tmp / "export/model.onnx")
    assert len(runs) == 1
    assert {k: v.shape[0] for k, v in runs[0].items()} == dict.fromkeys(model._inputs, 1)
    assert all(not v.any() for v in runs[0].values())
    d = FLUID_SMALL.simulate(64, np.random.default_rng(2))
    model.predict(d["ze"], d["t"])
    assert len(runs) == 2 and len(runs[1]["ze_re"]) == 64
    record = SimpleNamespace(name="e", type="tensor(float)", shape=["batch", "n_samples"])
    stub = SimpleNamespace(session=SimpleNamespace(get_inputs=lambda: [record],
                                                   run=lambda *a: runs.append(a)))
    OnnxModel._first_run_at_batch_1(stub)
    assert len(runs) == 2
