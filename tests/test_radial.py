"""The radial slice: its scene on the beam model, baselines, bound, decoders, export, bench."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import RADIAL_SMALL

from wtml.baselines.radial import BayesRadial, InversionRadial, PolynomialRadial
from wtml.bench.bounds import radial_crlb
from wtml.bench.radial import generation_throughput, run_bench
from wtml.data import load_shards
from wtml.decoders.checkpoint import read_checkpoint
from wtml.decoders.layers import StandardPolynomial
from wtml.decoders.radial import GateParts, RadialNet, TorchRadial, load_radial_net
from wtml.physics import ze_from_zm
from wtml.runtime.predict import OnnxModel, predict_file
from wtml.scenes import RadialScene, SceneError, load_scene
from wtml.schema import build, to_dict

ROOT = Path(__file__).resolve().parents[1]
SMALL = RADIAL_SMALL


def test_shipped_scenes_load_and_bad_values_are_named(tmp_path):
    scene = load_scene(ROOT / "configs/scenes/radial.yaml")
    assert scene.excitation.frequencies_hz[0] == 420.0 and scene.device.name == "micro"
    assert scene.spread.none  # the shipped scene: the preset's own device
    spread = load_scene(ROOT / "configs/scenes/radial_spread.yaml")
    assert spread.spread.modulus == 0.03 and spread.spread.length == 0.005
    assert dataclasses.replace(spread, name=scene.name, spread=scene.spread) == scene
    invalid = load_scene(ROOT / "configs/scenes/radial_invalid.yaml")
    assert invalid.contact.distances_um == (500.0, 1500.0, 2500.0)
    bad = tmp_path / "bad.yaml"
    bad.write_text("task: radial\ncontact:\n  distance_um: [0, 6000]\n")
    with pytest.raises(SceneError, match=r"contact.distance_um: must stay below the whisker"):
        load_scene(bad)
    bad.write_text("task: radial\nexcitation:\n  frequencies_hz: [420, -1]\n")
    with pytest.raises(SceneError, match=r"excitation.frequencies_hz\[1\]: must be in"):
        load_scene(bad)


def test_contact_at_the_tip_is_the_tip_load_of_the_two_port():
    """The beam path with the contact at d = 0 equals the 2×2 path with Zm = k/(jω)."""
    scene = SMALL
    tr = scene.transducer()
    k = np.array([1e3, 3e4])
    ze_beam = scene.ze_of(np.zeros(2), k, tr)
    omega = scene.excitation.omega
    ze_matrix = ze_from_zm(tr.transduction_matrix(omega), k[:, None] / (1j * omega))
    np.testing.assert_allclose(ze_beam, ze_matrix, rtol=1e-9)


def test_inversion_recovers_noise_free_contacts():
    scene = build(RadialScene, {"noise": {"ze_relative": 0.0}})
    inv = InversionRadial(scene)
    d = np.array([100e-6, 1234e-6, 3000e-6])  # on the 1 µm grid
    ks = np.geomspace(*scene.contact.stiffness, 17)[[0, 8, 16]]  # on the stiffness grid
    ref = np.broadcast_to(scene.free_ze(), (3, 1))
    np.testing.assert_allclose(inv.predict(scene.ze_of(d, ks), ref)["distance"], d,
                               atol=0.05e-6)
    # between grid points, within one grid step
    off = d + 0.5e-6
    np.testing.assert_allclose(inv.predict(scene.ze_of(off, ks), ref)["distance"], off,
                               atol=1e-6)
    # a device that differs by a complex gain only: its reference corrects it exactly
    gain = 1.02 - 0.01j
    np.testing.assert_allclose(inv.predict(gain * scene.ze_of(d, ks), gain * ref)["distance"],
                               d, atol=0.05e-6)


def test_inversion_grid_start_is_the_least_misfit_table_entry(rng):
    """The grid start's expanded misfit (one matrix product) picks the table entry a direct
    search of ``Σ |(ze - table)/table|²`` picks, for noisy measurements anywhere in range,
    whether the misfits are taken all at once or 7 measurements at a time."""
    inv = InversionRadial(SMALL, step=20e-6)
    ze = SMALL.simulate(300, rng)["ze"]
    misfit = np.sum(np.abs((ze[:, None] - inv.table[None]) / inv.table[None]) ** 2, -1)
    d, lnk = inv.start(ze)
    np.testing.assert_array_equal(d, inv.table_d[np.argmin(misfit, -1)])
    np.testing.assert_array_equal(lnk, inv.table_lnk[np.argmin(misfit, -1)])
    chunked = inv.start(ze, chunk_bytes=7 * 8 * len(inv.table))
    np.testing.assert_array_equal(chunked[0], d)
    np.testing.assert_array_equal(chunked[1], lnk)


def test_polynomial_layer_matches_scikit_learn(rng):
    data = SMALL.simulate(2000, rng)
    for reference in (True, False):
        poly = PolynomialRadial("imag", reference=reference).fit(data["ze"], data["ref"],
                                                                 data["distance"])
        x = data["ze"][:, 0] / (data["ref"][:, 0] if reference else 1.0)
        layer = StandardPolynomial(9).load_pipeline(poly.model)
        got = layer(torch.tensor(x.imag, dtype=torch.float32)).double().numpy()
        np.testing.assert_allclose(got, poly.predict(data["ze"], data["ref"])["distance"],
                                   atol=0.05e-6)


def test_crlb_grows_with_noise_at_most_linearly():
    """Doubling σ quarters the data's information; the prior on ln k stays, so the bound grows,
    by at most 2x (exactly 2x only where the prior does not matter)."""
    d, k = np.array([0.2e-3, 1.6e-3, 3e-3]), np.array([1e4, 1e4, 1e4])
    quiet = radial_crlb(SMALL, d, k)
    loud = radial_crlb(build(RadialScene, {"noise": {"ze_relative": 4e-5}}), d, k)
    assert np.all(loud > 1.2 * quiet) and np.all(loud <= 2 * quiet * (1 + 1e-6))
    assert np.all(quiet > 0) and np.all(quiet < 20e-6)


def test_radial_net_options():
    net = RadialNet(5, [8], "sigmoid", uncertainty=False, used_frequencies=1)
    d, s = net(*(torch.ones(3, 5) for _ in range(4)))
    assert d.shape == s.shape == (3,) and torch.all(s == 0)
    # the thesis's net reads Ze alone: its answer ignores the reference
    thesis = RadialNet(5, [8], "sigmoid", used_frequencies=1, reference=False)
    ze = torch.rand(3, 5)
    assert torch.equal(thesis(ze, ze, ze, ze)[0], thesis(ze, ze, 2 * ze, ze)[0])
    assert not torch.equal(net(ze, ze, ze, ze)[0], net(ze, ze, 2 * ze, ze)[0])
    with pytest.raises(ValueError, match="used_frequencies"):
        RadialNet(5, [8], used_frequencies=6)
    with pytest.raises(ValueError, match="activation"):
        RadialNet(5, [8], activation="tanh")


def test_generation_throughput_is_reported():
    gen = generation_throughput(SMALL, n=500)
    assert gen["beam"] > 0 and gen["matrix"] > 0


def test_radial_onnx_matches_torch_and_predict_reads_it(radial_flow, tmp_path):
    tmp = radial_flow
    data = load_shards(tmp / "data", [3])
    ze, ref = data["ze"], data["ref"]
    for name in ("radial", "radial_thesis"):
        net, _ = load_radial_net(str(tmp / f"runs/{name}/checkpoints/last.ckpt"))
        want = TorchRadial(net).predict(ze, ref)
        got = OnnxModel(tmp / f"export/{name}/model.onnx").predict(ze, ref)
        np.testing.assert_allclose(got["distance"], want["distance"], rtol=1e-5, atol=1e-9)
    poly = OnnxModel(tmp / "export/radial/classical.onnx")
    assert poly.name == "polynomial 9 in Im Ze/ref ONNX"
    freq = np.array(SMALL.excitation.frequencies_hz)
    np.savez(tmp_path / "m.npz", frequency_hz=freq, ze=ze[:2])
    np.savez(tmp_path / "free.npz", frequency_hz=freq, ze=ref[:2])
    rows = predict_file(tmp / "export/radial", tmp_path / "m.npz", reference=tmp_path / "free.npz")
    assert len(rows) == 2 and "distance_decoder (m)" in rows[0] and "sigma_decoder (m)" in rows[0]
    # beside σ (the 68 % half-width) the 95 % one, the metadata's width of σ's range × σ
    rule = OnnxModel(tmp / "export/radial/model.onnx").intervals["sigma_95"]
    for row in rows:
        want = row["sigma_decoder (m)"] * rule.wide([row["distance_decoder (m)"]])[0]
        assert row["sigma_95_decoder (m)"] == pytest.approx(want, rel=1e-12)
        assert row["sigma_95_decoder (m)"] >= row["sigma_decoder (m)"] or not row["in_domain"]
    # one reference row serves every measurement; the export's own sample reference reads
    sample = tmp / "export/radial/sample_reference.npz"
    one = predict_file(tmp / "export/radial", tmp_path / "m.npz", reference=sample)
    assert len(one) == 2 and all(np.isfinite(r["distance_decoder (m)"]) for r in one)


def test_a_radial_export_without_its_reference_is_a_clear_error(radial_flow, tmp_path, capsys):
    """No --reference, one on another grid or of another row count, and a reference given
    to an export that takes none: each an InputError naming the flag, never a default."""
    import json

    import onnx

    from wtml.cli import main
    from wtml.runtime.predict import InputError

    tmp = radial_flow
    freq = np.array(SMALL.excitation.frequencies_hz)
    data = load_shards(tmp / "data", [3])
    np.savez(tmp_path / "m.npz", frequency_hz=freq, ze=data["ze"][:3])
    with pytest.raises(InputError, match=r"this radial export needs --reference: the free "
                                         r"whisker's Ze at 420 Hz \(npz with frequency_hz"):
        predict_file(tmp / "export/radial", tmp_path / "m.npz")
    assert main(["predict", "--model", str(tmp / "export/radial"), "--input",
                 str(tmp_path / "m.npz")]) != 0
    assert "needs --reference" in capsys.readouterr().err
    np.savez(tmp_path / "grid.npz", frequency_hz=freq + 1, ze=data["ref"][:3])
    with pytest.raises(InputError, match=r"--reference .*grid.npz: frequencies"):
        predict_file(tmp / "export/radial", tmp_path / "m.npz", reference=tmp_path / "grid.npz")
    np.savez(tmp_path / "rows.npz", frequency_hz=freq, ze=data["ref"][:2])
    with pytest.raises(InputError, match=r"\(3, 1\) for 3 measurements, got \(2, 1\)"):
        predict_file(tmp / "export/radial", tmp_path / "m.npz", reference=tmp_path / "rows.npz")
    with pytest.raises(InputError, match="needs a reference"):
        OnnxModel(tmp / "export/radial/model.onnx").predict(data["ze"])
    for name in ("model.onnx", "classical.onnx"):
        meta = {p.key: p.value for p in onnx.load(str(tmp / "export/radial" / name)).metadata_props}
        assert list(json.loads(meta["references"])) == ["reference"]
        assert json.loads(meta["inputs"]) == ["ze_re", "ze_im", "ref_re", "ref_im"]


def test_radial_bench_reports_every_method(radial_flow, tmp_path):
    tmp = radial_flow
    # the device-spread table's scene: the small scene with configs/scenes/radial_spread's
    # spread
    spread = tmp_path / "spread.yaml"
    widths = load_scene(ROOT / "configs/scenes/radial_spread.yaml").spread
    spread.write_text(json.dumps(to_dict(dataclasses.replace(SMALL, spread=widths))))
    report = run_bench(tmp / "data", tmp / "runs/radial/checkpoints/last.ckpt",
                       tmp / "runs/radial_thesis/checkpoints/last.ckpt", tmp / "export/radial",
                       tmp / "export/radial_thesis", tmp_path, invalid_dir=tmp / "invalid",
                       latency_repeats=5, throughput_repeats=1,
                       spread_scene=spread, spread_samples=20)
    for name in ("thesis 2-10-1 torch", "thesis 2-10-1 ONNX", "ours torch", "ours ONNX",
                 "polynomial 9 in Re Ze", "polynomial 9 in Im Ze", "polynomial 9 in Re Ze/ref",
                 "polynomial 9 in Im Ze/ref", "polynomial Im Ze/ref ONNX", "physics inversion"):
        assert f"| {name} |" in report
    assert "d = 1.5 mm" in report and "Generation: beam path" in report
    # the device-spread table: fresh records of the spread scene (no spread dataset here),
    # the shipped decoder and its peers; no spread-trained column without its export
    for row in ("| nominal device |", "| spread |", "| whisker.modulus ±3 % alone |",
                "| records | ours ONNX | thesis 2-10-1 ONNX | polynomial Im Ze/ref ONNX | "
                "physics inversion |"):
        assert row in report, row
    for png in ("error_vs_latency.png", "error_vs_d.png"):
        assert (tmp_path / png).stat().st_size > 10_000


def test_pipeline_resumes_only_a_checkpoint_of_the_same_scene_and_model(radial_flow, tmp_path):
    """The flow trained configs/radial.yaml for 2 epochs with coarse_epochs 1: the shipped
    config must not resume it, the same config with those overrides must; another scene or
    run length must not."""
    import yaml

    from wtml.data import read_manifest
    from wtml.pipeline import checkpoint_matches

    ckpt = radial_flow / "runs/radial/checkpoints/last.ckpt"
    scene_hash = read_manifest(radial_flow / "data")["scene_hash"]
    shipped = ROOT / "configs/radial.yaml"
    assert not checkpoint_matches(ckpt, scene_hash, str(shipped))
    cfg = yaml.safe_load(shipped.read_text())
    cfg["model"]["init_args"]["coarse_epochs"] = 1
    same = tmp_path / "same.yaml"
    same.write_text(yaml.safe_dump(cfg))
    assert checkpoint_matches(ckpt, scene_hash, str(same), max_epochs=2)
    assert not checkpoint_matches(ckpt, scene_hash, str(same), max_epochs=3)
    assert not checkpoint_matches(ckpt, scene_hash, str(same))  # the config's 100 epochs
    assert not checkpoint_matches(ckpt, "0" * 64, str(same), max_epochs=2)
    assert not checkpoint_matches(tmp_path / "none.ckpt", scene_hash, str(same))


# resuming into the run's own checkpoint folder is the point here; lightning remarks on it
@pytest.mark.filterwarnings("ignore:Checkpoint directory .* exists and is not empty")
def test_two_phase_training_resumes_in_its_refining_phase(radial_flow, tmp_path):
    """A 3-epoch run (coarse 1, refine 2) interrupted after epoch 2 resumes from last.ckpt
    with its schedule: the third epoch moves the refiner and leaves the coarse stage."""
    import lightning as L

    from wtml.data.datamodule import ShardDataModule
    from wtml.decoders.radial import RadialDecoder

    class StopAfterSecondEpoch(L.Callback):
        def on_train_epoch_end(self, trainer, module):
            trainer.should_stop = trainer.current_epoch == 1

    def fit(*callbacks, ckpt_path=None):
        L.seed_everything(0)
        dm = ShardDataModule(str(radial_flow / "data"), batch_size=100)
        model = RadialDecoder(hidden=[16], refine_hidden=[16], coarse_epochs=1)
        saver = L.pytorch.callbacks.ModelCheckpoint(dirpath=tmp_path / "ckpt", filename="last")
        trainer = L.Trainer(max_epochs=3, logger=False, enable_progress_bar=False,
                            enable_model_summary=False, log_every_n_steps=1,
                            callbacks=[saver, *callbacks])
        trainer.fit(model, dm, ckpt_path=ckpt_path)
        return read_checkpoint(tmp_path / "ckpt/last.ckpt")

    before = fit(StopAfterSecondEpoch())
    after = fit(ckpt_path=str(tmp_path / "ckpt/last.ckpt"))
    assert before["epoch"] == 1 and after["epoch"] == 2
    moved = {k for k, v in after["state_dict"].items()
             if not torch.equal(v, before["state_dict"][k])}
    assert moved and all(k.startswith("net.refine.") for k in moved)


def test_coarse_epochs_must_leave_epochs_for_the_refiner(radial_flow):
    import lightning as L

    from wtml.data.datamodule import ShardDataModule
    from wtml.decoders.radial import RadialDecoder

    trainer = L.Trainer(max_epochs=2, logger=False, enable_progress_bar=False,
                        enable_checkpointing=False, enable_model_summary=False)
    model = RadialDecoder(hidden=[4], refine_hidden=[4], coarse_epochs=2)
    with pytest.raises(ValueError, match=r"model.coarse_epochs must be in .*\[1, 1\], got 2"):
        trainer.fit(model, ShardDataModule(str(radial_flow / "data")))


def test_optimizer_is_checked():
    from wtml.decoders.radial import RadialDecoder

    with pytest.raises(ValueError, match=r"model.optimizer must be 'adamw' or 'lbfgs', got 'sgd'"):
        RadialDecoder(optimizer="sgd")
    with pytest.raises(ValueError, match=r"'lbfgs' trains a plain RadialNet only"):
        RadialDecoder(refine_hidden=[4], optimizer="lbfgs")
    with pytest.raises(ValueError, match=r"model.weight_decay must be 0 with model.optimizer"):
        RadialDecoder(optimizer="lbfgs", weight_decay=1e-4)


def test_spread_table_rows_and_their_numbers():
    """The device-spread table has the nominal device, the spread and every parameter of
    the scene's spread alone (nothing for a parameter the scene keeps nominal); a row's
    numbers: RMSE, max, in-domain answers within 2σ, flagged share."""
    from wtml.bench.radial import format_spread, spread_row, spread_sets

    scene = build(RadialScene, {"samples": 100, "shards": 1,
                                "spread": {"modulus": 0.03, "coupling": 0.01}})
    sets = spread_sets(scene, {"distance": np.zeros(4)}, {"distance": np.zeros(3)}, 5)
    assert list(sets) == ["nominal device", "spread",
                          "bimorph.modulus ±3 % alone", "whisker.modulus ±3 % alone",
                          "coupling ±1 % alone", "spread, whisker measured"]
    assert len(sets["nominal device"]["distance"]) == 4 and len(sets["spread"]["distance"]) == 3
    assert len(sets["coupling ±1 % alone"]["ze"]) == 5
    d = np.zeros(4)
    row = spread_row({"distance": np.array([1.0, -3.0, 0.5, 9.0]) * 1e-6,
                      "sigma": np.array([1.0, 1.0, 1.0, np.nan]) * 1e-6,
                      "in_domain": np.array([True, True, True, False])}, d)
    assert row["rmse"] == pytest.approx(np.sqrt((1 + 9 + 0.25 + 81) / 4) * 1e-6)
    assert row["max"] == pytest.approx(9e-6)
    assert row["cover"] == pytest.approx(2 / 3) and row["flagged"] == pytest.approx(0.25)
    plain = spread_row({"distance": np.array([1.0, -1, 1, -1]) * 1e-6}, d)
    assert np.isnan(plain["cover"]) and np.isnan(plain["flagged"])
    text = format_spread({"nominal device": {"ours": row, "inversion": plain}})
    assert "| nominal device | 4.78 / 9.00, 67 %, 25 % | 1.00 / 1.00 |" in text


def test_spread_variant_trains_reads_the_reference_and_exports(tmp_path):
    """configs/radial_spread.yaml on a small scene with a device spread: its net reads the
    reference's own values besides the ratio (the shipped one-device decoder does not), the
    answer moves with the reference, and the ONNX graph agrees with torch."""
    import os

    from wtml.cli import main
    from wtml.data import generate
    from wtml.training import cli_main

    spread = load_scene(ROOT / "configs/scenes/radial_spread.yaml").spread
    scene = dataclasses.replace(SMALL, samples=800, shards=4,
                                spread=dataclasses.replace(spread, devices=16))
    generate(scene, tmp_path / "data", progress=False)
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        cli_main(["fit", "--config", str(ROOT / "configs/radial_spread.yaml"),
                  "--data.init_args.data_dir", str(tmp_path / "data"),
                  "--trainer.max_epochs", "2", "--model.init_args.coarse_epochs", "1",
                  "--trainer.log_every_n_steps", "1"])
        assert main(["export", "--checkpoint", "runs/radial_spread/checkpoints/last.ckpt",
                     "--out", "export/radial_spread"]) == 0
    finally:
        os.chdir(cwd)
    net, _ = load_radial_net(str(tmp_path / "runs/radial_spread/checkpoints/last.ckpt"))
    n = net.n_freq
    assert net.device and net.refine_mean.shape == (4 * n + 1,)
    assert net.coarse.feature_mean.shape == (4 * n,)
    data = load_shards(tmp_path / "data", [3])
    ze, ref = data["ze"][:64], data["ref"][:64]
    want = TorchRadial(net).predict(ze, ref)
    got = OnnxModel(tmp_path / "export/radial_spread/model.onnx").predict(ze, ref)
    np.testing.assert_allclose(got["distance"], want["distance"], rtol=1e-5, atol=1e-9)
    other = TorchRadial(net).predict(ze, ref * (1 + 1e-3))
    assert not np.allclose(other["distance"], want["distance"], rtol=0, atol=1e-9)


def test_the_one_device_decoder_reads_the_ratio_only(radial_flow):
    """The shipped scene has no spread: its decoder's stages read ``ze / ref`` and
    ``(p, d0)`` alone (the references differ only by their noise)."""
    net, _ = load_radial_net(str(radial_flow / "runs/radial/checkpoints/last.ckpt"))
    n = net.n_freq
    assert not net.device and net.refine_mean.shape == (2 * n + 1,)
    assert net.coarse.feature_mean.shape == (2 * n,)


def test_the_gate_resolves_a_reference_a_noise_away_from_the_preset():
    """On one device the references differ from the preset's free Ze by their noise alone
    (~2e-6 of it): the gate's deviation ``u = ref / free - 1`` is computed from ``ref -
    free`` (exact in float32 that close), so its sum of squares is good to ~1e-6 of itself,
    where ``ref / free`` first and 1 subtracted after loses ~6e-8 of 1 (a few % of u)."""
    free = RADIAL_SMALL.free_ze()
    rng = np.random.default_rng(4)
    eps = 2e-6 * (rng.normal(size=(256, len(free))) + 1j * rng.normal(size=(256, len(free))))
    ref = free * (1 + eps)
    gate = GateParts(free, device=False)
    parts = [torch.tensor(p, dtype=torch.float32) for z in (ref, ref) for p in (z.real, z.imag)]
    got = gate(*parts)[:, -1].double().numpy()
    ref32, free32 = (z.real.astype(np.float32).astype(float)
                     + 1j * z.imag.astype(np.float32).astype(float) for z in (ref, free))
    u = ref32 / free32 - 1  # in float64, from the graph's own float32 inputs and constants
    np.testing.assert_allclose(got, (np.abs(u) ** 2).sum(-1), rtol=1e-5)


def test_the_bayes_posterior_mean_is_the_least_squares_error():
    """The posterior mean by importance sampling (the radial frontier's best achievable):
    on records of its own prior its RMSE is no worse than the MAP's (the physics inversion)
    and near the Cramér–Rao bound, with enough effective draws per measurement."""
    data = RADIAL_SMALL.simulate(300, np.random.default_rng(5))
    bayes = BayesRadial(RADIAL_SMALL)
    d = data["distance"]
    b = bayes.predict(data["ze"], data["ref"])["distance"]
    m = InversionRadial(RADIAL_SMALL).predict(data["ze"], data["ref"])["distance"]
    rms = lambda x: float(np.sqrt(np.mean(x**2)))  # noqa: E731
    crlb = rms(radial_crlb(RADIAL_SMALL, d, data["stiffness"]))
    assert rms(b - d) <= 1.02 * rms(m - d)
    assert 0.8 * crlb < rms(b - d) < 1.2 * crlb
    assert np.median(bayes.ess) > 50 and bayes.ess.min() > 5
    # the same draws on every call: the same answers
    assert np.array_equal(bayes.predict(data["ze"], data["ref"])["distance"], b)


def test_the_main_jobs_sample_measurements_leave_the_export_as_its_manifest_lists_it(
        radial_flow, tmp_path):
    """``wtml pipeline`` writes its sample CSV and their devices' references beside the export:
    every file the manifest lists still has its hash, and the references read."""
    import shutil

    from wtml.pipeline import write_sample_csv
    from wtml.runtime.metadata import read_manifest, verified_bytes

    export = tmp_path / "radial"
    shutil.copytree(radial_flow / "export/radial", export)
    refs = write_sample_csv(radial_flow / "data", export / "sample_input.csv")
    assert refs == {"reference": export / "sample_input_reference.npz"}
    for entry in read_manifest(export).files:
        verified_bytes(export, entry)  # raises on a changed file
    rows = predict_file(export, export / "sample_input.csv", **refs)
    assert len(rows) == 3 and all(np.isfinite(r["distance_decoder (m)"]) for r in rows)
