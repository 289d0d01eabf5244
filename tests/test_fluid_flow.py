"""The fluid flow end to end on a tiny dataset: train from the config (LightningCLI), resume,
export, ONNX parity with torch and numpy, and ``wtml predict`` on every input format."""

import csv
import os
import re
from pathlib import Path

import numpy as np
import onnx
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
from wtml.decoders.layers import ZmFromZe
from wtml.physics import zm_from_ze
from wtml.runtime.export import ClassicalFluidNet
from wtml.runtime.predict import InputError, OnnxModel, predict_file
from wtml.scenes import FluidScene
from wtml.scenes.config import build
from wtml.signals import sample_times, tone
from wtml.training import cli_main

ROOT = Path(__file__).resolve().parents[1]
SCENE = FLUID_SMALL  # the flow fixture's scene (conftest.py)


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
    ze = load_shards(tmp / "data", [3])["ze"]
    torch_pred = TorchFluid(net).predict(ze)
    onnx_pred = OnnxModel(tmp / "export/model.onnx").predict(ze)
    for k in ("eta", "rho"):
        np.testing.assert_allclose(onnx_pred[k], torch_pred[k], rtol=1e-5)
    with torch.no_grad():
        score = module.gate(torch.tensor(ze.real, dtype=torch.float32),
                            torch.tensor(ze.imag, dtype=torch.float32)).numpy()
    # a float32 quadratic form of standardised features: kernel differences reach 1.6e-4
    np.testing.assert_allclose(onnx_pred["domain_score"], score, rtol=1e-3)
    one = OnnxModel(tmp / "export/model.onnx").predict(ze[:1])
    np.testing.assert_allclose(one["eta"], torch_pred["eta"][:1], rtol=1e-5)


def test_classical_onnx_float32_matches_numpy_float64(flow):
    """The float32 graph differs from float64 numpy by what float32 loses in Ze -> Zm
    (test_float32.py), carried through the band least squares, which is linear:
    |Δη| <= Σ_k |P_ηk| |ΔZm_k| (P its pseudo-inverse), plus the float32 rounding of that
    sum. The ONNX graph and the same graph in torch agree to float32 kernel differences."""
    tmp, _ = flow
    ze = load_shards(tmp / "data", [3])["ze"]
    numpy_path = ClassicalFluid(SCENE.calibrated_t(), SCENE.excitation.omega, SCENE.sphere.radius)
    ref = numpy_path.predict(ze)
    net = ClassicalFluidNet(SCENE.calibrated_t(), SCENE.excitation.omega, SCENE.sphere.radius)
    ze_re = torch.tensor(ze.real, dtype=torch.float32)
    ze_im = torch.tensor(ze.imag, dtype=torch.float32)
    zr, zi = net.zm(ze_re, ze_im)
    zm64 = numpy_path.zm(ze)
    dzm = np.concatenate([np.abs(zr.double().numpy() - zm64.real),
                          np.abs(zi.double().numpy() - zm64.imag)], -1)
    x = np.concatenate([np.abs(zm64.real), np.abs(zm64.imag)], -1)
    eps32 = float(np.finfo(np.float32).eps)
    got = dict(zip(("eta", "rho"), (v.double().numpy() for v in net(ze_re, ze_im)), strict=True))
    for row, key in enumerate(("eta", "rho")):
        p = np.abs(numpy_path.pinv[row])
        bound = 1.5 * (dzm @ p) + 64 * eps32 * (x @ p)
        assert np.all(np.abs(got[key] - ref[key]) <= bound), key
    onnx_pred = OnnxModel(tmp / "export/classical.onnx").predict(ze)
    for key in ("eta", "rho"):
        scale = np.abs(ref[key]).max()
        np.testing.assert_allclose(onnx_pred[key], got[key], rtol=1e-5, atol=1e-6 * scale)


def test_zm_layer_matches_numpy():
    t = SCENE.calibrated_t()
    ze = SCENE.simulate(64, np.random.default_rng(0))["ze"]
    zr, zi = ZmFromZe(t)(torch.tensor(ze.real, dtype=torch.float32),
                         torch.tensor(ze.imag, dtype=torch.float32))
    ref = zm_from_ze(t, ze)
    np.testing.assert_allclose(zr.numpy() + 1j * zi.numpy(), ref, rtol=2e-5 * 10,
                               atol=1e-5 * np.abs(ref).max())
    eta, rho = ClassicalFluidNet(t, SCENE.excitation.omega, SCENE.sphere.radius)(
        torch.tensor(ze.real, dtype=torch.float32), torch.tensor(ze.imag, dtype=torch.float32))
    assert eta.shape == rho.shape == (64,)


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
    _write_csv(tmp_path / "m.csv", freq, ze)
    np.savez(tmp_path / "m.npz", frequency_hz=freq, ze=ze)
    # raw signals: a stepped sine, 40 periods per step at 20 kHz, E = 3 V, I = E/Ze
    fs = 20_000.0
    t = sample_times(0.4, fs)
    e = np.stack([[tone(t, f, 3.0) for f in freq]] * 2)
    i = np.stack([[tone(t, f, abs(3.0 / z), np.angle(3.0 / z))
                   for f, z in zip(freq, row, strict=True)] for row in ze])
    np.savez(tmp_path / "raw.npz", frequency_hz=freq, e=e, i=i, sample_rate_hz=fs)
    rows = {name: predict_file(tmp / "export", tmp_path / name)
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
    assert main(["predict", "--model", model, "--input", str(tmp_path / "m.csv")]) == 0
    assert "eta_decoder (Pa*s)" in capsys.readouterr().out


def test_predict_refuses_bad_input(flow, tmp_path):
    tmp, _ = flow
    freq = SCENE.excitation.frequency_hz
    ze = load_shards(tmp / "data", [3])["ze"][:1]
    np.savez(tmp_path / "grid.npz", frequency_hz=freq + 1.0, ze=ze)
    with pytest.raises(InputError, match=r"frequency grid 91-121 Hz \(31 points\) is not the "
                                         r"model's 90-120 Hz"):
        predict_file(tmp / "export", tmp_path / "grid.npz")
    bad = ze.copy()
    bad[0, 4] = np.nan
    np.savez(tmp_path / "nan.npz", frequency_hz=freq, ze=bad)
    with pytest.raises(InputError, match=r"NaN or inf at sample 0, 94 Hz"):
        predict_file(tmp / "export", tmp_path / "nan.npz")
    np.savez(tmp_path / "shape.npz", frequency_hz=freq, ze=ze[:, :30])
    with pytest.raises(InputError, match=r"shape \(n, n_freq=31\)"):
        predict_file(tmp / "export", tmp_path / "shape.npz")
    np.savez(tmp_path / "keys.npz", frequency_hz=freq, z=ze)
    with pytest.raises(InputError, match="needs 'ze'"):
        predict_file(tmp / "export", tmp_path / "keys.npz")
    (tmp_path / "x.txt").write_text("1")
    model = str(tmp / "export")
    assert main(["predict", "--model", model, "--input", str(tmp_path / "x.txt")]) == 2


def test_bench_reports_every_method(flow, tmp_path):
    tmp, ckpt = flow
    report = run_bench(tmp / "data", ckpt, tmp / "export", tmp_path, latency_repeats=5,
                       throughput_repeats=1)
    for name in ("thesis closed form numpy", "thesis closed form ONNX", "decoder torch",
                 "decoder ONNX", "Bayes posterior mean", "Cramér–Rao bound (no prior)"):
        assert f"| {name}" in report
    exact = re.search(r"max relative error η (\S+), ρ (\S+)\.\s", report)
    assert float(exact[1].rstrip(",")) <= 1e-9 and float(exact[2]) <= 1e-9
    assert (tmp_path / "report.md").read_text() == report
    assert (tmp_path / "error_vs_latency.png").stat().st_size > 10_000


def test_crlb_scales_with_noise_and_grows_with_calibration_error():
    eta, rho = np.array([1e-3, 1e-1]), np.array([1000.0, 1200.0])
    quiet = fluid_crlb(build(FluidScene, {"nuisance": {"calibration_error": 0.0}}), eta, rho)
    loud = fluid_crlb(build(FluidScene, {"nuisance": {"calibration_error": 0.0},
                                         "noise": {"ze_relative": 2e-4}}), eta, rho)
    np.testing.assert_allclose(loud["eta"], 2 * quiet["eta"], rtol=1e-3)  # linear in σ
    cal = fluid_crlb(build(FluidScene, {}), eta, rho)
    assert np.all(cal["eta"] > 10 * quiet["eta"]) and np.all(cal["rho"] > quiet["rho"])
