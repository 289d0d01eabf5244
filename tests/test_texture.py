"""The texture scene and decoder: the in-graph feature layer against numpy, the scene's
fidelity to the thesis (Table 4.10, Figures 4.28-4.31) and its kinetic signature."""

import numpy as np
import pytest
import torch

from wtml.decoders.texture import ModalT, WhiskFeatures, cholesky_solve
from wtml.fidelity import format_texture, texture_fidelity
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


def test_graph_t_is_the_modal_models(scene):
    model = scene.transducer()
    w = 2 * np.pi * np.array([30.0, 35.5, 36.0, 37.0, 45.0])
    t = model.transduction_matrix(w).reshape(-1, 4)
    parts = [p.double().numpy() for p in ModalT(model)(torch.tensor(w, dtype=torch.float32))]
    got = np.stack([parts[2 * k] + 1j * parts[2 * k + 1] for k in range(4)], 1)
    np.testing.assert_allclose(got, t, rtol=1e-5)


def test_features_recover_a_tone_and_are_the_same_for_any_window_start(scene):
    """A drive of 9 V at 35.7 Hz and a current with two harmonics: ω to 1e-6, and the
    features of two windows a non-integer number of cycles apart agree."""
    rate = scene.acquisition.sample_rate_hz
    t = np.arange(40000) / rate
    w = 2 * np.pi * 35.7
    e = 9 * np.sin(w * t + 0.3)
    i = 2e-5 * np.cos(w * t + 1.0) + 1e-6 * np.cos(3 * w * t + 0.2) + 3e-7 * np.sin(2 * w * t)
    feats = WhiskFeatures(scene.transducer(), rate)
    n = 12800
    x = torch.tensor(np.stack([e[:n], e[5000:5000 + n]]), dtype=torch.float32)
    y = torch.tensor(np.stack([i[:n], i[5000:5000 + n]]), dtype=torch.float32)
    omega, ce, ci, _ = feats.fit(x, y)
    np.testing.assert_allclose(omega.numpy(), w, rtol=1e-6)
    np.testing.assert_allclose(torch.hypot(ce[:, 1], ce[:, 2]).numpy(), 9, rtol=1e-5)
    f = feats(x, y).numpy()
    np.testing.assert_allclose(f[0, :11], f[1, :11], atol=2e-3)


def test_scene_reproduces_table_4_10_and_figures_4_28_to_4_31(scene):
    r = texture_fidelity(scene)
    assert np.all(np.abs(r["rms_speed"] / r["table_speed"] - 1) < 0.10)
    assert r["r2_force"] > 0.99 and r["r2_velocity"] > 0.99
    assert np.all(np.diff(r["force"]) > 0) and np.all(np.diff(r["velocity"]) < 0)
    assert np.all(np.diff(r["zm"].real) > 0)
    assert np.all(np.abs(r["zm"].imag) < 0.2 * r["zm"].real)
    text = format_texture(r)
    assert "Kinetic signature" in text


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
