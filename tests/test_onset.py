"""The onset slice: labels, the step's effect, the thesis pipeline's cross-check, and the
exported graphs (ONNX against torch, records read on a device)."""

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
import torch

from tests.conftest import ROOT
from wtml.runtime.onset import predict_records, read_record, thesis_pipeline
from wtml.runtime.predict import InputError, OnnxModel
from wtml.scenes import load_scene
from wtml.scenes.onset import intervals

SMALL = {"samples": 24, "shards": 3}


@pytest.fixture(scope="module")
def scene():
    base = load_scene(ROOT / "configs/scenes/onset.yaml")
    return dataclasses.replace(base, **SMALL)


def test_intervals_merge_touches_on_successive_probe_peaks():
    rate = 1000.0
    active = np.zeros((2, 100), bool)
    active[0, 10:12] = active[0, 14:16] = active[0, 40:50] = True  # gap 2 samples, then 24
    active[1, 90:] = True  # still touching at the end
    on, off = intervals(active, rate, merge_s=0.003, max_count=3)
    np.testing.assert_allclose(on[0, :2], [0.010, 0.040])
    np.testing.assert_allclose(off[0, :2], [0.016, 0.050])
    assert np.isnan(on[0, 2]) and on[1, 0] == 0.090 and np.isnan(off[1, 0])


def test_each_whisk_touches_once_near_where_the_whisking_position_reaches_the_wall(scene):
    """Two whisk cycles, two contacts, each starting on the first probe peak that reaches the
    wall: when the whisking position u_L = HUE(0) e_L is up to the probe's amplitude (0.224 µm
    at 420 Hz) short of g, and at most one probe period's whisking (0.11 µm) less (§10)."""
    exact = dataclasses.replace(scene, calibration_error=0.0)
    amp = exact.whisk_amplitude_m()
    gaps = np.array([0.3, 0.7]) * amp
    rec = exact.simulate(2, np.random.default_rng(0), gaps=gaps)
    t_reach = np.arccos(-gaps / amp) / (2 * np.pi)  # u_L = -amp cos(2π t) = g
    for r in range(2):
        on, off = rec["onset"][r], rec["detachment"][r]
        assert np.sum(np.isfinite(on)) == 2 and np.all(off[:2] > on[:2])
        lead = t_reach[r] - on[0]  # how much earlier than u_L reaches g
        speed = 2 * np.pi * np.sqrt(amp**2 - gaps[r] ** 2)  # whisking speed there, m/s
        assert 0.224e-6 - speed / 420 - 0.01e-6 < lead * speed < 0.23e-6, lead * speed
        assert abs(on[1] - on[0] - 1.0) < 2e-3  # the second whisk repeats the first


def test_halving_the_step_moves_the_onsets_by_less_than_the_scene_allows(scene):
    """The onset and detachment times at twice the sampling rate move by less than 2 coarse
    steps (75 µs: 6 nm of whisking at most, below the scene's 1 % calibration error)."""
    fine = dataclasses.replace(scene, acquisition=dataclasses.replace(
        scene.acquisition, sample_rate_hz=2 * scene.acquisition.sample_rate_hz))
    gaps = np.array([0.5]) * scene.whisk_amplitude_m()
    a = scene.simulate(1, np.random.default_rng(1), gaps=gaps)
    b = fine.simulate(1, np.random.default_rng(1), gaps=gaps)
    for key in ("onset", "detachment"):
        ok = np.isfinite(a[key])
        assert np.array_equal(ok, np.isfinite(b[key]))
        assert np.max(np.abs(a[key][ok] - b[key][ok])) < 2 / scene.acquisition.sample_rate_hz


def test_thesis_pipeline_lands_just_beyond_the_wall_without_noise(scene):
    """physics.md §10's independent cross-check: the thesis pipeline locates the wall 0.25 to
    0.77 µm beyond it (k_c = 5 N/m, no noise, no calibration error)."""
    quiet = dataclasses.replace(
        scene, calibration_error=0.0,
        acquisition=dataclasses.replace(scene.acquisition, e_noise_v=0.0, i_noise_a=0.0),
        wall=dataclasses.replace(scene.wall, stiffness=(5.0, 5.0)))
    amp = quiet.whisk_amplitude_m()
    gaps = np.array([0.3, 0.6]) * amp
    rec = quiet.simulate(2, np.random.default_rng(2), gaps=gaps)
    with torch.no_grad():
        gap = thesis_pipeline(quiet)(torch.tensor(rec["e"]), torch.tensor(rec["i"]))[0].numpy()
    beyond = gap - gaps
    assert np.all((beyond > 0.1e-6) & (beyond < 1.0e-6)), beyond


@pytest.fixture(scope="module")
def onset_export(tmp_path_factory, scene):
    """A tiny onset flow: generate, train 3 epochs, export."""
    import yaml

    root = tmp_path_factory.mktemp("onset")
    cfg = root / "scene.yaml"
    cfg.write_text(yaml.safe_dump({"name": "onset", "task": "onset", **SMALL}))
    data, run, model = root / "data", root / "run", root / "export"
    subprocess.run([sys.executable, "-m", "wtml.cli", "generate", "--config", str(cfg),
                    "--out", str(data)], check=True, capture_output=True, cwd=ROOT)
    subprocess.run([sys.executable, "train.py", "fit", "--config", "configs/onset.yaml",
                    "--data.init_args.data_dir", str(data), "--trainer.max_epochs", "3",
                    "--trainer.default_root_dir", str(run)], check=True, capture_output=True,
                   cwd=ROOT)
    subprocess.run([sys.executable, "-m", "wtml.cli", "export", "--checkpoint",
                    str(run / "checkpoints/last.ckpt"), "--out", str(model)], check=True,
                   capture_output=True, cwd=ROOT)
    return {"data": data, "run": run, "model": model}


def test_exported_graphs_match_torch(onset_export, scene):
    from wtml.decoders.checkpoint import load_decoder
    from wtml.decoders.domain import Gated

    module = load_decoder(onset_export["run"] / "checkpoints/last.ckpt")
    rec = scene.simulate(3, np.random.default_rng(5))
    with torch.no_grad():
        ref = Gated(module.net, module.gate, (1,)).eval()(torch.tensor(rec["e"]),
                                                          torch.tensor(rec["i"]))
        ref_cl = thesis_pipeline(scene)(torch.tensor(rec["e"]), torch.tensor(rec["i"]))
    dec = OnnxModel(onset_export["model"] / "model.onnx").run(rec["e"], rec["i"])
    cl = OnnxModel(onset_export["model"] / "classical.onnx").run(rec["e"], rec["i"])
    np.testing.assert_allclose(dec["gap"], ref[0].numpy(), rtol=1e-4, atol=1e-10)
    np.testing.assert_allclose(dec["contact"], ref[2].numpy(), atol=1e-4)
    np.testing.assert_array_equal(dec["in_domain"], ref[3].numpy())
    np.testing.assert_allclose(cl["gap"], ref_cl[0].numpy(), rtol=1e-4, atol=1e-10)
    assert np.mean(cl["contact"] == ref_cl[2].numpy()) > 0.9999


def test_predict_reads_records_resamples_and_refuses(onset_export, scene, tmp_path):
    rec = scene.simulate(1, np.random.default_rng(6))
    rate = scene.acquisition.sample_rate_hz
    path = tmp_path / "rec.npz"
    np.savez(path, e=rec["e"][0], i=rec["i"][0], sample_rate_hz=rate)
    rows = predict_records(onset_export["model"], path)
    assert {r["method"] for r in rows} == {"decoder", "classical"}
    # the same record at twice the rate is resampled to the trained one
    from scipy.signal import resample_poly

    double = tmp_path / "double.npz"
    np.savez(double, e=resample_poly(rec["e"][0], 2, 1), i=resample_poly(rec["i"][0], 2, 1),
             sample_rate_hz=2 * rate)
    x = read_record(double, rate, scene.n_samples)
    assert x.shape == (2, 1, scene.n_samples)
    np.testing.assert_allclose(x[1, 0, 2000:-2000], rec["i"][0, 2000:-2000],
                               atol=2e-3 * np.abs(rec["i"]).max())
    odd = tmp_path / "odd.npz"
    np.savez(odd, e=rec["e"][0], i=rec["i"][0], sample_rate_hz=rate * np.pi / 3)
    with pytest.raises(InputError, match="not a ratio of whole numbers"):
        read_record(odd, rate, scene.n_samples)
    short = tmp_path / "short.npz"
    np.savez(short, e=rec["e"][0, :1000], i=rec["i"][0, :1000], sample_rate_hz=rate)
    with pytest.raises(InputError, match="the model takes records of"):
        read_record(short, rate, scene.n_samples)
    bad = tmp_path / "bad.npz"
    np.savez(bad, e=rec["e"][0], sample_rate_hz=rate)
    with pytest.raises(InputError, match="missing \\['i'\\]"):
        read_record(bad, rate, scene.n_samples)
