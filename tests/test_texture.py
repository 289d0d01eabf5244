"""The texture scene and decoder: the in-graph feature layer against numpy, the scene's
fidelity to the thesis (Table 4.10, Figures 4.28-4.31) and its kinetic signature."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from tests.conftest import TEXTURE_SMALL, TEXTURE_SPREAD
from wtml.decoders.texture import BandPowers, CalibratedT, WhiskFeatures, cholesky_solve
from wtml.fidelity import format_texture, texture_fidelity
from wtml.physics.spread import DeviceSpread
from wtml.physics.twoport import flat_parts
from wtml.runtime import metadata as md
from wtml.scenes import load_scene
from wtml.scenes.texture import TextureScene


@pytest.fixture(scope="module")
def scene() -> TextureScene:
    return load_scene("configs/scenes/texture.yaml")


def test_unrolled_cholesky_solves_like_numpy():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((3, 7, 7))
    g = a @ a.transpose(0, 2, 1) + 7 * np.eye(7)
    b = rng.standard_normal((3, 7, 2))
    x = cholesky_solve(torch.tensor(g), torch.tensor(b)).numpy()
    np.testing.assert_allclose(x, np.linalg.solve(g, b), rtol=1e-10, atol=1e-12)


def test_calibrated_t_interpolates_the_users_t_to_the_measured_omega(scene):
    """T on the scene's five calibration frequencies (the graph's input), interpolated in the
    graph to ω anywhere on the whisking range and a little beyond it, is the modal model's T
    at ω to float32 rounding (1e-5 of each element's largest value): the graph needs no
    model of the device, only its calibration. Each sample gets its own T."""
    grid = scene.calibration_hz
    assert grid[0] < scene.drive.whisk_hz[0] and grid[-1] > scene.drive.whisk_hz[1]
    w = 2 * np.pi * np.array([34.6, 35.0, 35.73, 36.0, 36.41, 37.0, 37.4])
    models = [scene.transducer(), scene.transducer({"bimorph.modulus": 1.03,
                                                    "loss_factor": 0.75})]
    t_re, t_im = flat_parts(np.stack([scene.calibrated_t(models[k % 2]) for k in range(7)]))
    parts = [p.double().numpy() for p in CalibratedT(grid)(
        torch.tensor(w, dtype=torch.float32), torch.tensor(t_re), torch.tensor(t_im))]
    got = np.stack([parts[2 * k] + 1j * parts[2 * k + 1] for k in range(4)], 1)
    want = np.stack([models[k % 2].transduction_matrix(w[k]).reshape(4) for k in range(7)])
    scale = np.abs(want).max(0)
    assert np.all(np.abs(got - want) <= 1e-5 * scale)
    # and the two devices' T differ by far more than that: the input matters
    other = np.stack([models[(k + 1) % 2].transduction_matrix(w[k]).reshape(4)
                      for k in range(7)])
    assert np.all(np.abs(other - want).max(0) > 1e-2 * scale)


def test_features_recover_a_tone_and_are_the_same_for_any_window_start(scene):
    """A drive of 9 V at 35.7 Hz and a current with two harmonics: ω to 1e-6, and the
    features of two windows a non-integer number of cycles apart agree."""
    rate = scene.acquisition.sample_rate_hz
    t = np.arange(40000) / rate
    w = 2 * np.pi * 35.7
    e = 9 * np.sin(w * t + 0.3)
    i = 2e-5 * np.cos(w * t + 1.0) + 1e-6 * np.cos(3 * w * t + 0.2) + 3e-7 * np.sin(2 * w * t)
    feats = WhiskFeatures(scene.calibration_hz, rate)
    n = 12800
    x = torch.tensor(np.stack([e[:n], e[5000:5000 + n]]), dtype=torch.float32)
    y = torch.tensor(np.stack([i[:n], i[5000:5000 + n]]), dtype=torch.float32)
    omega, ce, ci, _ = feats.fit(x, y)
    np.testing.assert_allclose(omega.numpy(), w, rtol=1e-6)
    np.testing.assert_allclose(torch.hypot(ce[:, 1], ce[:, 2]).numpy(), 9, rtol=1e-5)
    t_re, t_im = (torch.tensor(np.stack([p, p])) for p in
                  flat_parts(scene.calibrated_t(scene.transducer())))
    f = feats(x, y, t_re, t_im).numpy()
    np.testing.assert_allclose(f[0, :11], f[1, :11], atol=2e-3)


def test_band_powers_put_a_tone_in_its_band_and_white_noise_across_all(scene):
    """A 5 kHz tone of amplitude 3 at an odd window length (frames left over at its end):
    A²/2 in all, at least 95 % of it in the band that holds 5 kHz (the Hann frame's main lobe
    spills into the next band for the rest); unit white noise: the bands' share of the
    Nyquist band, each band's power proportional to its width to 8 %."""
    rate = scene.acquisition.sample_rate_hz
    bands = BandPowers(rate, 1024)
    assert bands.n_bands == 38 and abs(bands.edges[0] - 951.4) < 0.1
    t = np.arange(5000) / rate
    tone = bands(torch.tensor(3 * np.sin(2 * np.pi * 5003.0 * t + 0.4)[None],
                              dtype=torch.float32))[0].numpy()
    k = np.searchsorted(bands.edges, 5003.0) - 1
    assert tone.sum() == pytest.approx(4.5, rel=1e-3)
    assert tone[k] > 0.95 * 4.5 and np.argmax(tone) == k
    noise = bands(torch.tensor(np.random.default_rng(0).standard_normal((200, 5000)),
                               dtype=torch.float32)).numpy().mean(0)
    share = np.diff(bands.edges) / (rate / 2)
    np.testing.assert_allclose(noise, share, rtol=0.08)
    with pytest.raises(ValueError, match="shorter than a frame"):
        bands(torch.zeros(1, 1000))
    with pytest.raises(ValueError, match="even"):
        BandPowers(rate, 1023)


def test_band_features_are_the_residuals_power_over_the_force(scene):
    """The decoder's band columns are ln(band power / |F|²): scaling e and i together (a
    stronger drive of the same linear device: the force and the asperities' current scale
    alike) leaves them as they were, and scaling the broadband part of i alone by c moves
    each by 2 ln c, while the whisk features stay put. Without ``band_frame`` the columns
    are the whisk features alone."""
    rate = scene.acquisition.sample_rate_hz
    n = 12800
    t = np.arange(n) / rate
    w = 2 * np.pi * 35.7
    rng = np.random.default_rng(1)
    e = 9 * np.sin(w * t + 0.3)
    tone = 2e-5 * np.cos(w * t + 1.0) + 1e-6 * np.cos(3 * w * t + 0.2)
    broad = 1e-7 * rng.standard_normal(n)
    t_re, t_im = (torch.tensor(np.stack([p] * 3)) for p in
                  flat_parts(scene.calibrated_t(scene.transducer())))
    feats = WhiskFeatures(scene.calibration_hz, rate, 1024)
    assert feats.n_features == WhiskFeatures.N_FEATURES + 38
    x = feats(torch.tensor(np.stack([e, 2 * e, e]), dtype=torch.float32),
              torch.tensor(np.stack([tone + broad, 2 * (tone + broad), tone + 3 * broad]),
                           dtype=torch.float32), t_re, t_im).double().numpy()
    cut = WhiskFeatures.N_FEATURES
    np.testing.assert_allclose(x[1, cut:], x[0, cut:], atol=1e-3)
    np.testing.assert_allclose(x[2, cut:] - x[0, cut:], 2 * np.log(3), atol=0.02)
    np.testing.assert_allclose(x[2, :7], x[0, :7], atol=1e-3)
    plain = WhiskFeatures(scene.calibration_hz, rate)
    assert plain.n_features == cut
    np.testing.assert_allclose(plain(torch.tensor(e[None], dtype=torch.float32),
                                     torch.tensor((tone + broad)[None], dtype=torch.float32),
                                     t_re[:1], t_im[:1]).double().numpy()[0],
                               x[0, :cut], atol=1e-6)


def test_the_high_branch_reads_nothing_below_its_band(scene):
    """The decoder's second branch reads the whisk cues and the bands from ``high_band_hz``
    up: a 2 kHz tone added to the current (where held-out LuGre moved the features most)
    moves the columns of the low bands by orders of magnitude and leaves the high branch's
    columns within float32 rounding."""
    from wtml.decoders.texture import TextureDecoder

    rate = scene.acquisition.sample_rate_hz
    n = 12800
    t = np.arange(n) / rate
    w = 2 * np.pi * 35.7
    e = 9 * np.sin(w * t + 0.3)
    base = 2e-5 * np.cos(w * t + 1.0) + 1e-7 * np.random.default_rng(2).standard_normal(n)
    ring = 3e-6 * np.sin(2 * np.pi * 2000.0 * t)
    t_re, t_im = (torch.tensor(np.stack([p] * 2)) for p in
                  flat_parts(scene.calibrated_t(scene.transducer())))
    decoder = TextureDecoder()
    feats = decoder.feature_layer(scene)
    cues, first = decoder.high_columns(feats)
    assert cues == WhiskFeatures.CUE_COLUMNS == 11
    assert feats.bands.edges[first - WhiskFeatures.N_FEATURES] == pytest.approx(
        25600 / 2 ** (21 / 8))  # 4.15 kHz: the first band edge at or above 4 kHz
    x = feats(torch.tensor(np.stack([e, e]), dtype=torch.float32),
              torch.tensor(np.stack([base, base + ring]), dtype=torch.float32),
              t_re, t_im).double().numpy()
    high = np.r_[0:cues, first:x.shape[1]]
    np.testing.assert_allclose(x[1, high], x[0, high], atol=2e-3)
    at = WhiskFeatures.N_FEATURES + np.searchsorted(feats.bands.edges, 2000.0) - 1
    assert x[1, at] - x[0, at] > 5  # the tone's band: its power e^5 times the noise's
    assert TextureDecoder(high_band_hz=None).high_columns(feats) is None


def test_two_branches_answer_as_the_geometric_mean_and_the_mixture(scene):
    """With its high branch the net's probabilities are the normalised geometric mean of the
    two branches', and its ln grain the equal mixture's mean and std; the high branch reads
    only its columns (the residual's RMS, lags and low bands may change freely); the loss is
    each branch's own loss, summed, not the loss of the pair's answer."""
    from torch.nn import functional as fn

    from wtml.decoders.texture import TextureDecoder

    decoder = TextureDecoder(hidden=[8])
    feats = decoder.feature_layer(scene)
    torch.manual_seed(0)
    x = torch.randn(6, feats.n_features)
    y = torch.tensor([[k % 5, 3e-5 * (1 + k / 10)] for k in range(6)])
    net = decoder.net_on(feats, x, y)
    decoder.net = net
    (la, ma, sa), (lb, mb, sb) = (tuple(v.detach().double() for v in b)
                                  for b in net.branches(x))
    grain, log_sd, prob = (v.detach().double() for v in net.from_features(x))
    want = torch.sqrt(torch.softmax(la, -1) * torch.softmax(lb, -1))
    torch.testing.assert_close(prob, want / want.sum(-1, keepdim=True))
    torch.testing.assert_close(torch.log(grain), (ma + mb) / 2)
    var = (torch.exp(2 * sa) + torch.exp(2 * sb)) / 2 + ((ma - mb) / 2) ** 2
    torch.testing.assert_close(log_sd, torch.log(var) / 2)
    cues, first = net.high_columns
    moved = x.clone()
    moved[:, cues:first] += 5.0
    full, high = net.branches(moved)
    torch.testing.assert_close(high[0].detach().double(), lb)
    assert not torch.allclose(full[0].detach().double(), la)
    moved = x.clone()
    moved[:, first] += 5.0
    assert not torch.allclose(net.branches(moved)[1][0].detach().double(), lb)

    def own(logits, mu, lsd):
        z = (torch.log(y[:, 1]) - mu) / torch.exp(lsd)
        return fn.cross_entropy(logits, y[:, 0].long()) + 0.5 * (0.5 * z**2 + lsd).mean()

    torch.testing.assert_close(decoder.feature_loss(x, y),
                               sum(own(*b) for b in net.branches(x)))
    assert abs(float((decoder.feature_loss(x, y) - own(*net.heads(x))).detach())) > 1e-3


def test_a_run_resumed_from_before_the_high_branch_keeps_one_branch(scene):
    """A checkpoint saved before ``high_band_hz`` existed has no such argument: a resumed run
    rebuilds its one branch (its weights load strictly), where the config's default would
    build two and refuse them."""
    from wtml.decoders.texture import TextureDecoder
    from wtml.training import resumed_arguments

    saved = {"hidden": [8], "window_s": 0.25, "grain_weight": 0.5, "band_frame_s": 0.01,
             "lr": 3e-3, "weight_decay": 1e-4}
    feats = TextureDecoder().feature_layer(scene)
    x = torch.randn(6, feats.n_features)
    y = torch.tensor([[k % 5, 3e-5] for k in range(6)])
    weights = TextureDecoder(**saved, high_band_hz=None).net_on(feats, x, y).state_dict()
    args = resumed_arguments(TextureDecoder, saved)
    assert args["high_band_hz"] is None and args["band_frame_s"] == 0.01
    TextureDecoder(**args).net_on(feats, x, y).load_state_dict(weights)
    with pytest.raises(RuntimeError, match="high"):
        TextureDecoder(**saved).net_on(feats, x, y).load_state_dict(weights)
    assert resumed_arguments(TextureDecoder, saved | {"high_band_hz": 4000.0})[
        "high_band_hz"] == 4000.0


@pytest.mark.parametrize("dynamo", [False, True], ids=["torchscript", "torch.export"])
def test_band_powers_export_to_onnx_as_torch_computes_them(scene, tmp_path, dynamo):
    """The band block alone through each of torch's exporters (the TorchScript one that
    :func:`wtml.exporters.graphs.export_graph` uses, and torch.export's, its successor; a
    dynamic batch) and onnxruntime, at a window length whose frames do not tile it, and at a
    batch other than the traced one: the torch powers to 1e-5 of the largest."""
    import warnings

    import onnxruntime as ort

    bands = BandPowers(scene.acquisition.sample_rate_hz, 1024).eval()
    x = torch.tensor(np.random.default_rng(2).standard_normal((3, 5000)), dtype=torch.float32)
    path = tmp_path / "bands.onnx"
    if dynamo:
        torch.onnx.export(bands, (x[:2],), str(path), input_names=["x"], output_names=["p"],
                          dynamo=True, external_data=False,
                          dynamic_shapes=({0: torch.export.Dim("batch", min=1)},),
                          verbose=False)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)  # the exporter's own notice
            warnings.simplefilter("ignore", torch.jit.TracerWarning)  # the frame count
            torch.onnx.export(bands, (x[:2],), str(path), input_names=["x"],
                              output_names=["p"], dynamo=False, opset_version=18,
                              dynamic_axes={"x": {0: "batch"}, "p": {0: "batch"}})
    got = ort.InferenceSession(str(path)).run(None, {"x": x.numpy()})[0]
    want = bands(x).numpy()
    assert got.shape == want.shape == (3, 38)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * want.max())


def test_scene_reproduces_table_4_10_and_figures_4_28_to_4_31(scene):
    r = texture_fidelity(scene)
    assert np.all(np.abs(r["rms_speed"] / r["table_speed"] - 1) < 0.10)
    assert r["r2_force"] > 0.99 and r["r2_velocity"] > 0.99
    assert np.all(np.diff(r["force"]) > 0) and np.all(np.diff(r["velocity"]) < 0)
    assert np.all(np.diff(r["zm"].real) > 0)
    assert np.all(np.abs(r["zm"].imag) < 0.2 * r["zm"].real)
    text = format_texture(r)
    assert "Kinetic signature" in text


def test_fidelity_checks_a_viscous_span_on_each_law_of_the_mixture(scene):
    """Without a span nothing is added; with one, each law of the mixture's moved line at the
    span's top meets Table 4.10 (the report says so), and a wrong shift (none) is reported."""
    from dataclasses import replace

    assert texture_fidelity(scene)["span_speed"] == {}
    spanned = replace(scene, friction=replace(scene.friction, viscous_span=1e-4))
    r = texture_fidelity(spanned)
    assert set(r["span_speed"]) == {"coulomb", "stribeck"}
    for v in r["span_speed"].values():
        assert np.all(np.abs(v / r["table_speed"] - 1) < 0.10)
    text = format_texture(r)
    assert text.count("At the viscous span's top") == 2 and "(worst" in text
    unmoved = replace(spanned, friction=replace(spanned.friction, mu_0_per_c=0.0,
                                                mu_per_um_per_c=0.0, viscous_span=3e-4))
    assert "RMS speed within 10 % of Table 4.10: NO" in format_texture(
        texture_fidelity(unmoved)).split("At the viscous span's top")[1]


def test_no_kinetic_signature_in_the_current(scene):
    """The current's spectral peaks are shared by all grades and none sits at v/d."""
    r = texture_fidelity(scene)
    for k, peaks in enumerate(r["peaks_i"]):
        assert not np.any(np.abs(peaks / r["v_over_d"][k] - 1) < 0.05)
    first = r["peaks_i"][0]
    shared = [p for p in first if all(np.any(np.abs(q / p - 1) < 0.03) for q in r["peaks_i"])]
    assert len(shared) >= 3


def test_scene_records_and_labels(scene):
    from dataclasses import replace

    small = replace(scene, specimens_per_grade=1)
    d = small.simulate(5, np.random.default_rng(0))
    assert d["e"].shape == (5, small.n_samples) and d["i"].dtype == np.float32
    np.testing.assert_array_equal(d["grade"], np.arange(5))
    assert np.all(np.isfinite(d["i"])) and np.all(d["rms_speed"] > 0.05)


ISSUE_SPREAD = TEXTURE_SPREAD


def _short(scene, **device):
    """The scene with 0.1 s records (0.2 s lead-in) and the device spread ``device``."""
    from dataclasses import replace

    from wtml.physics.spread import DeviceSpread

    return replace(scene, specimens_per_grade=1, spread=DeviceSpread(**device),
                   drive=replace(scene.drive, record_s=0.1, lead_s=0.2))


def test_zero_spread_is_the_preset_bit_for_bit(scene):
    """All widths zero (the default, whatever ``devices``) draws nothing: the records are the
    preset's, bit for bit (checked against the code before the device block at the commit
    that added it), and every record's T is the preset's calibrated T."""
    nominal = _short(scene)
    zero = _short(scene, devices=7)
    a, b = nominal.simulate(6, np.random.default_rng(3)), zero.simulate(6, np.random.default_rng(3))
    for key in ("e", "i", "t", "rms_speed", "coupling"):
        np.testing.assert_array_equal(a[key], b[key])
    preset = nominal.calibrated_t(nominal.transducer())
    assert a["t"].shape == (6, len(nominal.calibration_hz), 2, 2)
    np.testing.assert_array_equal(a["t"], np.broadcast_to(preset, a["t"].shape))


def test_each_record_carries_its_drawn_devices_calibrated_t(scene, monkeypatch):
    """The devices a spread scene draws are the ones simulated and the T each record carries
    is its own device's (the decoder's input); the drawn devices differ from the preset by
    the stated tolerances; the specimens and nuisance are those of the nominal device's
    records (the draw comes after them). And the physics: through its own T a record's e and i
    give the tip speed the simulation had (1 s lead-in: the 36 Hz mode's transient gone),
    where the preset's T misses it."""
    from dataclasses import replace

    from wtml.decoders.texture import WhiskFeatures
    from wtml.scenes.texture import TextureScene

    quiet = _short(scene, **ISSUE_SPREAD)
    quiet = replace(quiet, drive=replace(quiet.drive, record_s=0.25, lead_s=1.0))

    from wtml.signals.acquisition import AcquisitionEffects

    quiet = replace(quiet, calibration_error=0.0, acquisition=replace(
        quiet.acquisition, effects=AcquisitionEffects().only()))
    drawn = {}
    original = TextureScene.devices

    def spy(self, n, rng):
        drawn["models"], drawn["index"] = original(self, n, rng)
        return drawn["models"], drawn["index"]

    monkeypatch.setattr(TextureScene, "devices", spy)
    rec = quiet.simulate(6, np.random.default_rng(4))
    models, index = drawn["models"], drawn["index"]
    assert len(models) == 6 and sorted(index.tolist()) == list(range(6))
    for r in range(6):
        np.testing.assert_array_equal(rec["t"][r], quiet.calibrated_t(models[index[r]]))
    preset = quiet.transducer()
    ratio = np.array([m.omega_n[0] / preset.omega_n[0] for m in models])
    assert np.all(np.abs(ratio - 1) < 0.03) and np.ptp(ratio) > 1e-3  # √(±3 % modulus) ...
    monkeypatch.undo()
    nominal = replace(quiet, spread=replace(quiet.spread, **dict.fromkeys(ISSUE_SPREAD, 0.0)))
    same = nominal.simulate(6, np.random.default_rng(4))
    for key in ("grade", "mu", "whisk_v", "whisk_hz", "normal_force", "angle"):
        np.testing.assert_array_equal(rec[key], same[key])

    feats = WhiskFeatures(quiet.calibration_hz, quiet.acquisition.sample_rate_hz)

    def speed(t):
        t_re, t_im = (torch.tensor(x) for x in flat_parts(t))
        _, (_, _, v_re, v_im, _, _), _ = feats.cues(torch.tensor(rec["e"]),
                                                    torch.tensor(rec["i"]), t_re, t_im)
        return np.hypot(v_re.double().numpy(), v_im.double().numpy()) / np.sqrt(2)

    own = speed(rec["t"]) / rec["rms_speed"] - 1
    wrong = speed(np.broadcast_to(quiet.calibrated_t(preset), rec["t"].shape)) / rec[
        "rms_speed"] - 1
    # measured: own within 0.96 % (the harmonics' share of the RMS speed), the preset's T
    # 5.7 % off at worst
    assert np.all(np.abs(own) < 0.015), own
    assert np.abs(wrong).max() > 3 * np.abs(own).max(), (own, wrong)


SMALL = TEXTURE_SMALL


def test_exported_graphs_match_torch_and_compute_the_features_once(texture_export, scene):
    """The ONNX decoder against the torch net and gate each computing their own features,
    on records of devices drawn from the spread, each window through its own device's T (the
    graph's t_re, t_im), and the ONNX thesis cues against torch; the gate and both nets share
    one feature layer. The export says which reference it needs, and where."""
    from dataclasses import replace

    from wtml.baselines.texture_classical import ClassicalTexture
    from wtml.decoders.checkpoint import load_decoder
    from wtml.decoders.domain import Gated
    from wtml.decoders.recalibration import Recalibrated, recalibrated
    from wtml.runtime.predict import OnnxModel

    module = load_decoder(texture_export["run"] / "checkpoints/last.ckpt")
    graph = Gated(module.net, module.gate, (1,)).eval()
    assert graph.shared and module.gate.features is module.net.features
    n = module._n
    spread = replace(scene, **SMALL)
    assert not spread.spread.none  # the shipped scene's tolerances
    rec = spread.simulate(5, np.random.default_rng(7))
    assert len({rec["t"][r].tobytes() for r in range(5)}) == 5  # a device per record
    e, i = rec["e"][:, :n], rec["i"][:, :n]
    t_re, t_im = flat_parts(rec["t"])
    with torch.no_grad():
        et, it, tr, ti = (torch.tensor(x) for x in (e, i, t_re, t_im))
        grain, _, prob = module.net(et, it, tr, ti)  # features computed by the net itself
        score = module.gate(et, it, tr, ti)  # and again by the gate
        # the same windows through the preset's T: another answer (T is used)
        nominal = torch.tensor(np.broadcast_to(t_re[:1], t_re.shape).copy())
        other = module.gate.features(et, it, nominal, torch.tensor(
            np.broadcast_to(t_im[:1], t_im.shape).copy()))
        assert (other - module.gate.features(et, it, tr, ti)).abs().amax() > 1e-3
    onnx = OnnxModel(texture_export["model"] / "model.onnx")
    assert json.loads(onnx.metadata["inputs"]) == ["e", "i", "t_re", "t_im"]
    assert "calibration" in onnx.references
    np.testing.assert_allclose(json.loads(onnx.metadata["calibration_hz"]),
                               spread.calibration_hz)
    dec = onnx.run(e, i, t_re, t_im)
    np.testing.assert_allclose(dec["grain"], grain.numpy(), rtol=1e-4)
    # the export recalibrates the net's probabilities (issue 25 §4)
    np.testing.assert_allclose(dec["probabilities"],
                               recalibrated(prob.numpy(), onnx.uncertainty), atol=2e-5)
    # and its grain interval reaches each grade as likely as that grade's threshold, at least
    rule = onnx.uncertainty.intervals[0]
    assert rule.classes == "probabilities" and len(rule.thresholds) == 5
    np.testing.assert_allclose(rule.class_values, np.array([15.3, 21.8, 35.0, 46.2, 52.2]) * 1e-6)
    with torch.no_grad():  # before the gate, which leaves σ NaN out of domain
        mine = [x.numpy() for x in Recalibrated(module.net, scene.OUTPUTS, onnx.uncertainty)(
            et, it, tr, ti)]
    np.testing.assert_allclose(mine[0], dec["grain"], rtol=1e-5)
    reach = md.class_reach(mine[0], mine[2], rule.class_values, rule.thresholds, True)
    assert np.all(np.exp(mine[1]) >= reach * (1 - 1e-6))
    inside = np.isfinite(dec["log_sigma"])
    np.testing.assert_allclose(dec["log_sigma"][inside], mine[1][inside], atol=1e-5)
    np.testing.assert_allclose(dec["domain_score"], score.numpy(), rtol=1e-3, atol=1e-5)
    assert OnnxModel(texture_export["model"] / "classical.onnx").metadata["kind"] == "classical"

    # the thesis cues: fitted on one record per grade, exported, against torch
    from wtml.exporters.graphs import export_graph

    fit = replace(scene, specimens_per_grade=1).simulate(5, np.random.default_rng(9))
    classical = ClassicalTexture.fit(module.net.features, fit["e"], fit["i"], fit["t"],
                                     fit["grade"], fit["grain_m"], n)
    cl_graph = Gated(classical, module.gate.inputs_only()).eval()
    assert cl_graph.shared
    path = texture_export["model"].parent / "classical_test.onnx"
    k = len(spread.calibration_hz)
    export_graph(cl_graph, n, path, {"outputs": json.dumps(list(scene.OUTPUTS))},
            ("e", "i", "t_re", "t_im"), (n, n, (k, 4), (k, 4)))
    import onnxruntime as ort

    session = ort.InferenceSession(str(path))
    cl = dict(zip((o.name for o in session.get_outputs()),
                  session.run(None, {"e": e, "i": i, "t_re": t_re, "t_im": t_im}),
                  strict=True))
    with torch.no_grad():
        ref = classical(et, it, tr, ti)
    np.testing.assert_allclose(cl["grain"], ref[0].numpy(), rtol=1e-4)
    np.testing.assert_allclose(cl["probabilities"], ref[2].numpy(), atol=1e-4)
    np.testing.assert_allclose(cl["domain_score"], score.numpy(), rtol=1e-3, atol=1e-5)


def test_the_bench_window_table_runs_the_checkpoint_and_the_export(texture_export):
    """The texture bench's accuracy-against-window-length table on the flow's test shard (as
    ``wtml bench texture`` runs it): the checkpoint's graph in torch at every window length,
    the export's windows pooled where a length is a multiple of its own, and the two graphs'
    probabilities on the trained windows within float32 rounding: the torch graph is the
    export's, recalibration included (the bench had compared the raw net with the tempered
    export and printed the temperature's 1.7e-2 as their difference). The main job had also
    failed here on float64 windows fed to the float32 torch graph, with no test to tell."""
    from wtml.bench.texture import WINDOWS_S, _by_window, export_in_torch
    from wtml.data.datamodule import split_shards
    from wtml.data.shards import dataset_scene, load_shards, read_manifest
    from wtml.runtime.predict import load_export

    data = texture_export["data"]
    scene = dataset_scene(data)
    test = load_shards(data, split_shards(read_manifest(data)["n_shards"], 1, 1)["test"])
    decoder = load_export(texture_export["model"])[0]
    window_s = json.loads(decoder.metadata["window_s"])
    graph = export_in_torch(texture_export["run"] / "checkpoints/last.ckpt", decoder)
    rows, parity = _by_window(test, graph, decoder, window_s,
                              scene.acquisition.sample_rate_hz)
    torch_rows = [r for r in rows if r["name"] == "decoder graph (torch)"]
    assert [r["window_s"] for r in torch_rows] == list(WINDOWS_S)
    pooled = {r["window_s"] for r in rows if r["name"] != "decoder graph (torch)"}
    assert pooled == {s for s in WINDOWS_S if s >= window_s and (s / window_s) % 1 == 0}
    assert all(r["n"] > 0 and 0 <= r["accuracy"] <= 1 and np.isfinite(r["latency_s"])
               for r in rows)
    assert parity < 1e-4


def test_predict_prints_grades_per_record(texture_export, scene, tmp_path):
    from wtml.runtime.predict import InputError
    from wtml.runtime.texture import predict_records

    rec = scene.simulate(2, np.random.default_rng(8))
    path, cal = tmp_path / "rec.npz", tmp_path / "cal.npz"
    np.savez(path, e=rec["e"], i=rec["i"], sample_rate_hz=scene.acquisition.sample_rate_hz)
    with pytest.raises(InputError, match="needs --calibration"):
        predict_records(texture_export["model"], path)  # never a default device
    np.savez(cal, frequency_hz=scene.calibration_hz[:-1], t=rec["t"][:, :-1])
    with pytest.raises(InputError, match="is not the model's"):
        predict_records(texture_export["model"], path, calibration=cal)
    np.savez(cal, frequency_hz=scene.calibration_hz, t=rec["t"])
    rows = predict_records(texture_export["model"], path, calibration=cal)
    assert [(r["record"], r["method"]) for r in rows] == [
        (0, "decoder"), (1, "decoder"), (0, "classical"), (1, "classical")]
    for r in rows:
        total = sum(v for k, v in r.items() if k.startswith("p("))
        assert abs(total - 1) < 1e-6 and r["grade"] in scene.class_names()
        assert 1 < r["grain (um)"] < 1000


TEXTURE_EDITS = {
    "window": ({"n_samples": "100"}, "metadata window_s: must be n_samples / sample_rate_hz"),
    "one class": ({"classes": '["P1200"]'}, "metadata classes: must name two or more"),
    "no calibration grid": ({"calibration_hz": "[]"}, "metadata calibration_hz"),
    "another task": ({"task": "onset"}, "metadata frame_s: missing"),
    "grid of another size": ({"calibration_hz": "[1, 2, 3]"},
                             "metadata calibration_hz: says input 't_re'"),
    "no domain outputs": ({"domain": json.dumps({
        "score": "x", "quantile": 0.999, "false_alarm_fresh": 0.0, "n_fresh": 1,
        "outputs": {}})}, "metadata domain.outputs: must give the ranges of 'grain'"),
}


def export_copy(texture_export, scene, tmp_path):
    """A copy of the texture flow's export under ``tmp_path`` to edit, a record of ``scene``
    and its calibration to predict on: ``(folder, record .npz, calibration .npz)``."""
    import shutil

    folder = tmp_path / "export"
    shutil.copytree(texture_export["model"], folder)
    rec = scene.simulate(1, np.random.default_rng(8))
    path, cal = tmp_path / "rec.npz", tmp_path / "cal.npz"
    np.savez(path, e=rec["e"], i=rec["i"], sample_rate_hz=scene.acquisition.sample_rate_hz)
    np.savez(cal, frequency_hz=scene.calibration_hz, t=rec["t"])
    return folder, path, cal


@pytest.mark.parametrize("name", sorted(TEXTURE_EDITS))
def test_a_texture_export_with_edited_metadata_is_one_line(texture_export, scene, tmp_path,
                                                           capsys, name):
    """Metadata edits made consistent with the manifest are refused by the schema: one line
    naming the file and the key."""
    from tests.test_export_files import edit_metadata, one_line

    folder, path, cal = export_copy(texture_export, scene, tmp_path)
    change, needle = TEXTURE_EDITS[name]
    edit_metadata(folder, "classical.onnx", **change)
    one_line(capsys, ["predict", "--model", str(folder), "--input", str(path),
                      "--calibration", str(cal)], "classical.onnx: " + needle)


@pytest.mark.parametrize("edit", ["classes of another output", "a class value short"])
def test_a_texture_decoder_whose_grade_thresholds_are_edited_is_one_line(
        texture_export, scene, tmp_path, capsys, edit):
    """The grain interval's per-grade reach reads the recalibrated probabilities, one value per
    class the graph names: an edit that breaks either is refused by name, not a numpy
    broadcast error (or a silently wrong width at a batch of five)."""
    from tests.test_export_files import edit_metadata, one_line

    folder, path, cal = export_copy(texture_export, scene, tmp_path)
    u = json.loads(onnx_metadata(folder / "model.onnx")["uncertainty"])
    rule = u["intervals"][0]
    if edit == "classes of another output":
        rule["classes"], needle = "grain", "intervals[0].classes: must be the recalibrated"
    else:
        rule["class_values"] = rule["class_values"][:4]
        rule["thresholds"], rule["thresholds_wide"] = (rule[k][:4] for k in (
            "thresholds", "thresholds_wide"))
        needle = "intervals[0].class_values: must hold one value per class (5), got 4"
    edit_metadata(folder, "model.onnx", uncertainty=json.dumps(u))
    one_line(capsys, ["predict", "--model", str(folder), "--input", str(path),
                      "--calibration", str(cal)], "model.onnx: metadata uncertainty.", needle)


def onnx_metadata(path) -> dict[str, str]:
    """An ONNX file's metadata, ``{key: value}``."""
    import onnx

    return {p.key: p.value for p in onnx.load(str(path)).metadata_props}


def test_a_checkpoint_keeps_its_band_frame_and_high_branch_and_one_from_before_has_none():
    """The net's shape carries its band frame (samples) and its high branch's frequency, so a
    checkpoint is rebuilt as it was trained; one saved before the band powers existed (no
    frame in its shape) is rebuilt without them, and one saved before the high branch
    without it, whatever the decoder's defaults."""
    from wtml.decoders.texture import TextureDecoder
    from wtml.schema import to_dict

    scene = to_dict(load_scene("configs/scenes/texture.yaml"))
    old = TextureDecoder()
    old.scene = scene
    old.build_from_checkpoint({"window": 12800})
    assert old.net.features.bands is None
    assert old.net.features.n_features == WhiskFeatures.N_FEATURES
    assert old.net.high is None
    assert old.net_shape() == {"window": 12800, "band_frame": None, "high_band_hz": None}
    banded = TextureDecoder(band_frame_s=None)
    banded.scene = scene
    banded.build_from_checkpoint({"window": 12800, "band_frame": 512})
    assert banded.net.features.bands.frame == 512 and banded.net.high is None
    assert banded.net_shape() == {"window": 12800, "band_frame": 512, "high_band_hz": None}
    new = TextureDecoder(high_band_hz=None)
    new.scene = scene
    new.build_from_checkpoint({"window": 12800, "band_frame": 512, "high_band_hz": 4000.0})
    start = new.net.features.bands.edges[new.net.high_columns[1] - WhiskFeatures.N_FEATURES]
    assert new.net.high is not None and 4000.0 <= start < 4000.0 * 2 ** (1 / 8)
    assert new.net_shape()["high_band_hz"] == 4000.0


def test_records_carry_t_at_the_frequencies_a_decoder_was_calibrated_on(scene):
    """A scene whose whisking range is narrowed (a bench's condition at one end of it) has
    its own calibration frequencies, not the trained scene's: fed to a decoder trained on
    the wide range, its records' T would be interpolated from the wrong frequencies (the
    stability bench's texture rows until 2 Dec: 26 % of windows at 36.8-37 Hz flagged, their
    Im Zm off by ~0.2 mN·s/m). ``calibration_hz`` gives T at the decoder's frequencies: the
    device's own T there, and the whisk inside the narrowed range."""
    narrow = dataclasses.replace(
        scene, samples=1, spread=DeviceSpread(),
        drive=dataclasses.replace(scene.drive, whisk_hz=(36.8, 37.0)))
    assert np.abs(narrow.calibration_hz - scene.calibration_hz).max() > 0.5  # the trap
    rec = narrow.simulate_independent(1, np.random.default_rng(0),
                                      calibration_hz=scene.calibration_hz)
    want = narrow.transducer().transduction_matrix(2 * np.pi * scene.calibration_hz)
    np.testing.assert_allclose(rec["t"][0], want, rtol=1e-12)
    assert 36.8 <= rec["whisk_hz"][0] <= 37.0
    own = narrow.simulate_independent(1, np.random.default_rng(0))  # the scene's own, as before
    np.testing.assert_allclose(
        own["t"][0], narrow.transducer().transduction_matrix(2 * np.pi * narrow.calibration_hz),
        rtol=1e-12)
    np.testing.assert_array_equal(own["i"], rec["i"])  # T is read after the records are made
