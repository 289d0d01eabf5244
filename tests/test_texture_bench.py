"""The texture bench's references: the amplitude oracle's exact limits, the kinetic-signature
classifier's rule, and the MiniRocket peer on a problem it must solve."""

import dataclasses

import numpy as np
import pytest
import torch

from wtml.baselines.ridge_gcv import BlockRidgeClassifierCV
from wtml.baselines.texture_peers import KineticSignature, MiniRocketPeer
from wtml.bench.texture import _cut, _torch, amplitude_oracle, confusion
from wtml.decoders.texture import BandPowers, WhiskFeatures
from wtml.scenes import load_scene
from wtml.scenes.texture import THESIS_GRADES, TextureScene

RATE = 51200.0


@pytest.fixture(scope="module")
def scene() -> TextureScene:
    return load_scene("configs/scenes/texture.yaml")


def test_confusion_counts_rows_as_truth():
    m = confusion(np.array([0, 0, 1, 2]), np.array([0, 1, 1, 2]), 3)
    np.testing.assert_array_equal(m, [[1, 1, 0], [0, 1, 0], [0, 0, 1]])


def test_amplitude_oracle_is_perfect_without_spread_and_loses_to_the_nuisance(scene):
    """With no specimen spread and one normal force and angle, the two amplitudes name the
    grade exactly; the scene's own prior makes P320 and P280 overlap; a wider normal-force
    range can only lower it."""
    exact = dataclasses.replace(
        scene, friction=dataclasses.replace(scene.friction, mu_spread=0.0,
                                            asperity_spread=0.0, grain_spread=(0.3, 0.3)),
        contact=dataclasses.replace(scene.contact, normal_force=(3.3e-4, 3.3e-4),
                                    angle_deg=(10.0, 10.0)))
    assert amplitude_oracle(exact, 20000)["accuracy"] == 1.0
    own = amplitude_oracle(scene, 50000)
    conf = np.array(own["confusion"], float)
    conf /= conf.sum(1, keepdims=True)
    assert 0.8 < own["accuracy"] < 0.99
    assert conf[3, 4] + conf[4, 3] > 10 * (conf[0, 1] + conf[1, 0])  # the coarse pair mixes
    wide = dataclasses.replace(scene, contact=dataclasses.replace(
        scene.contact, normal_force=(1.5e-4, 6e-4)))
    assert amplitude_oracle(wide, 50000)["accuracy"] < own["accuracy"]


def test_every_grain_oracle_gains_what_the_grains_carry(scene):
    """Seeing the grains swept adds to the amplitudes; the longer the sweep (more grains seen)
    or the more regular the grains, the more it adds; with nearly regular grains it names the
    grade."""
    sweep = np.full(5, 3e-3)
    own = amplitude_oracle(scene, 40000)["accuracy"]
    counted = amplitude_oracle(scene, 40000, sweep_m=sweep)["accuracy"]
    longer = amplitude_oracle(scene, 40000, sweep_m=10 * sweep)["accuracy"]
    assert own < counted < longer
    regular = dataclasses.replace(scene, friction=dataclasses.replace(
        scene.friction, grain_spread=(0.01, 0.02)))
    assert amplitude_oracle(regular, 40000, sweep_m=sweep)["accuracy"] > 0.995


def test_kinetic_signature_finds_a_planted_peak_and_names_the_nearest_v_over_d(scene):
    t = np.arange(12800) / RATE
    e = np.tile(10 * np.sin(2 * np.pi * 36 * t), (3, 1))
    i = np.tile(2e-5 * np.sin(2 * np.pi * 36 * t), (3, 1))
    tones = np.array([2000.0, 6000.0, 15000.0])
    i += 1e-7 * np.sin(2 * np.pi * tones[:, None] * t)
    sizes = np.array(list(THESIS_GRADES.values())) * 1e-6
    kin = KineticSignature(WhiskFeatures(scene.calibration_hz, RATE), sizes, RATE)
    np.testing.assert_allclose(kin.peaks(i), tones, atol=RATE / 2048)
    cal = np.broadcast_to(scene.calibrated_t(scene.transducer()), (3, 5, 2, 2))
    v = kin.speed(e, i, cal)
    assert np.all(v > 0) and np.ptp(v) < 1e-6 * v.max()
    got = kin.predict(e, i, cal)
    expected = np.argmin(np.abs(np.log(v[:, None] / sizes / kin.peaks(i)[:, None])), 1)
    np.testing.assert_array_equal(got["grade"], expected)
    np.testing.assert_allclose(got["grain"], v / kin.peaks(i))


def test_minirocket_separates_two_textures_of_different_roughness():
    """Windows whose current carries broadband noise of two different levels: a trivial
    problem for the peer (its channels are scaled by their training std)."""
    rng = np.random.default_rng(0)
    n, length = 40, 512
    t = np.arange(length) / RATE
    grade = np.arange(n) % 2
    e = 10 * np.sin(2 * np.pi * 36 * t + rng.uniform(0, 6, (n, 1)))
    i = 2e-5 * np.sin(2 * np.pi * 36 * t) + np.where(grade[:, None] == 1, 3e-7, 1e-8) \
        * rng.standard_normal((n, length))
    peer = MiniRocketPeer(n_kernels=500)
    with pytest.raises(RuntimeError, match="before fit"):
        peer.predict(e, i)
    peer.fit(e[:30], i[:30], grade[:30])
    out = peer.predict(e[30:], i[30:])
    np.testing.assert_array_equal(out["grade"], grade[30:])
    assert np.all(np.isnan(out["grain"]))


def test_minirocket_fit_stacked_is_fit_without_the_copy(monkeypatch):
    """The bench's path (windows stacked once in float32, scaled in place) fits the same peer
    as :meth:`MiniRocketPeer.fit` on e and i, and refuses float64 (it would copy after all);
    its scale is numpy's std of each channel though summed 5 windows at a time; stacked
    windows predict as e and i do."""
    from wtml.baselines import texture_peers

    monkeypatch.setattr(texture_peers, "TRANSFORM_WINDOWS", 5)
    rng = np.random.default_rng(1)
    n, length = 24, 256
    grade = np.arange(n) % 2
    e = 3.0 + rng.standard_normal((n, length))
    i = 1e-6 * rng.standard_normal((n, length)) * np.where(grade[:, None] == 1, 3.0, 1.0)
    x = np.stack([e, i], 1).astype(np.float32)
    np.testing.assert_allclose(MiniRocketPeer._channel_std(x).ravel(),
                               x.std(axis=(0, 2), dtype=np.float64), rtol=1e-6)
    stacked = MiniRocketPeer(n_kernels=200).fit_stacked(x, grade)
    plain = MiniRocketPeer(n_kernels=200).fit(e, i, grade)
    np.testing.assert_array_equal(stacked.scale, plain.scale)
    np.testing.assert_allclose(x.std(axis=(0, 2)), 1.0, rtol=1e-5)  # consumed: scaled in place
    np.testing.assert_array_equal(stacked.predict(e, i)["grade"], plain.predict(e, i)["grade"])
    np.testing.assert_array_equal(
        stacked.predict_stacked(np.stack([e, i], 1).astype(np.float32))["grade"],
        stacked.predict(e, i)["grade"])
    with pytest.raises(TypeError, match="float32"):
        MiniRocketPeer(n_kernels=200).fit_stacked(x.astype(np.float64), grade)


def test_minirocket_peer_is_aeons_classifier_transformed_a_few_windows_at_a_time(monkeypatch):
    """The peer's pipeline, its features made 5 windows at a time, is aeon's
    MiniRocketClassifier with the same seed and kernels: the same decision function and
    predictions on held-out windows (3 grades; the fit scaled both alike)."""
    from aeon.classification.convolution_based import MiniRocketClassifier

    from wtml.baselines import texture_peers

    monkeypatch.setattr(texture_peers, "TRANSFORM_WINDOWS", 5)
    rng = np.random.default_rng(2)
    n, length = 36, 300
    grade = np.arange(n) % 3
    e = rng.standard_normal((n, length))
    i = 1e-6 * rng.standard_normal((n, length)) * (1.0 + grade[:, None])
    peer = MiniRocketPeer(n_kernels=168, seed=4).fit(e[:27], i[:27], grade[:27])
    x = np.stack([e, i], 1).astype(np.float32) / peer.scale
    aeon = MiniRocketClassifier(n_kernels=168, random_state=4, n_jobs=1).fit(x[:27], grade[:27])
    np.testing.assert_allclose(peer.model.decision_function(x[27:].copy()),
                               aeon.pipeline_.decision_function(x[27:]), rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(peer.predict(e[27:], i[27:])["grade"], aeon.predict(x[27:]))


@pytest.mark.parametrize("classes", [2, 5])
def test_the_blockwise_ridge_is_scikit_learns_ridge_classifier_cv(classes):
    """Long features (more rows than features, offset and mixed so that centring and the
    unpenalised intercept matter), blocks of 37 rows (not a divisor of n): every penalty's
    leave-one-out score, the penalty chosen (inside the grid, not at an end), the
    coefficients, the intercept, the decision function and the classes are scikit-learn's;
    the caller's features are left as they were. float32 features far from zero fit as their
    float64 values do; features that say nothing take the first penalty, as scikit-learn."""
    from sklearn.linear_model import RidgeClassifierCV

    alphas = np.logspace(-3, 3, 10)
    rng = np.random.default_rng(classes)
    n, p = 170, 60
    grade = rng.integers(0, classes, n) * 10 + 3  # labels that are not 0..k-1
    mix = rng.normal(size=(p, p))
    x = (rng.normal(size=(n, p)) + 2.4 * np.eye(classes, p)[(grade - 3) // 10]) @ mix * 0.1 + 2
    before = x.copy()
    ref = RidgeClassifierCV(alphas=alphas, store_cv_results=True).fit(x, grade)
    ours = BlockRidgeClassifierCV(alphas, block=37).fit(x, grade)
    np.testing.assert_array_equal(x, before)
    np.testing.assert_allclose(ours.cv_scores_, -ref.cv_results_.reshape(n, -1, 10).mean((0, 1)),
                               rtol=1e-10)
    assert ours.alpha_ == ref.alpha_ and alphas[0] < ours.alpha_ < alphas[-1]
    np.testing.assert_allclose(ours.best_score_, ref.best_score_, rtol=1e-10)
    assert ours.coef_.shape == ref.coef_.shape == ((p,) if classes == 2 else (classes, p))
    np.testing.assert_allclose(ours.coef_, ref.coef_, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(ours.intercept_, ref.intercept_, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ours.decision_function(x), ref.decision_function(x),
                               rtol=1e-8, atol=1e-10)
    np.testing.assert_array_equal(ours.predict(x), ref.predict(x))
    assert (ours.predict(x) == grade).mean() > 0.8  # a problem the ridge solves
    # float32 features far from zero: summed in float64, the same fit as their float64 values
    far = (x * 0.01 + 1e4).astype(np.float32)
    as_f64 = BlockRidgeClassifierCV(alphas, block=37).fit(far.astype(np.float64), grade)
    as_f32 = BlockRidgeClassifierCV(alphas, block=37).fit(far, grade)
    np.testing.assert_allclose(as_f32.cv_scores_, as_f64.cv_scores_, rtol=1e-12)
    np.testing.assert_allclose(as_f32.coef_, as_f64.coef_, rtol=1e-10, atol=1e-12)
    # features that say nothing: every penalty scores alike, and the first is taken
    flat = BlockRidgeClassifierCV(alphas, block=37).fit(np.ones((n, 3)), grade)
    assert flat.alpha_ == RidgeClassifierCV(alphas=alphas).fit(np.ones((n, 3)), grade).alpha_ \
        == alphas[0]


def test_the_blockwise_ridge_refuses_what_it_cannot_fit():
    """Wide features (scikit-learn's gram mode is the lean one there), a NaN (named by its
    rows' block), one class, y that is not one class per row of x (fewer, or a column),
    x that is not 2-D, penalties that are not > 0, and a decision before the fit: each a
    clear error."""
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(50, 4)), np.arange(50) % 3
    with pytest.raises(ValueError, match="more rows than features"):
        BlockRidgeClassifierCV().fit(x[:4], y[:4])
    bad = x.copy()
    bad[21, 2] = np.nan
    with pytest.raises(ValueError, match="rows 20-29"):
        BlockRidgeClassifierCV(block=10).fit(bad, y)
    with pytest.raises(ValueError, match="two classes"):
        BlockRidgeClassifierCV().fit(x, np.zeros(50))
    for bad_y in (y[:-1], y[:, None]):  # (n, 1) would broadcast to (n, n) targets
        with pytest.raises(ValueError, match="one class per row"):
            BlockRidgeClassifierCV().fit(x, bad_y)
    with pytest.raises(ValueError, match=r"features \(n, p\)"):
        BlockRidgeClassifierCV().fit(x[:, 0], y)
    for alphas in ([], [1.0, 0.0], [np.inf]):
        with pytest.raises(ValueError, match="alphas"):
            BlockRidgeClassifierCV(alphas).fit(x, y)
    with pytest.raises(ValueError, match="block"):
        BlockRidgeClassifierCV(block=0).fit(x, y)
    with pytest.raises(RuntimeError, match="before fit"):
        BlockRidgeClassifierCV().predict(x)


def test_minirocket_peer_with_more_windows_than_features_is_still_aeons(monkeypatch):
    """Past its features (84 kernels, 150 training windows), the peer's ridge is the blockwise
    one (blocks of 16 rows), and the peer is still aeon's MiniRocketClassifier: the same
    penalty, decision function and predictions on held-out windows."""
    from aeon.classification.convolution_based import MiniRocketClassifier

    from wtml.baselines import ridge_gcv

    monkeypatch.setattr(ridge_gcv, "BLOCK", 16)
    rng = np.random.default_rng(3)
    n, length, train = 180, 200, 150
    grade = np.arange(n) % 3
    e = rng.standard_normal((n, length))
    i = 1e-6 * rng.standard_normal((n, length)) * (1.0 + 0.4 * grade[:, None])
    peer = MiniRocketPeer(n_kernels=84, seed=5).fit(e[:train], i[:train], grade[:train])
    ridge = peer.model[-1]
    assert isinstance(ridge, BlockRidgeClassifierCV) and ridge.coef_.shape[1] < train
    x = np.stack([e, i], 1).astype(np.float32) / peer.scale
    aeon = MiniRocketClassifier(n_kernels=84, random_state=5, n_jobs=1).fit(x[:train],
                                                                          grade[:train])
    assert ridge.alpha_ == aeon.pipeline_[-1].alpha_
    np.testing.assert_allclose(peer.model.decision_function(x[train:].copy()),
                               aeon.pipeline_.decision_function(x[train:]), rtol=1e-4,
                               atol=1e-5)
    np.testing.assert_array_equal(peer.predict(e[train:], i[train:])["grade"],
                                  aeon.predict(x[train:]))


def test_bench_windows_keep_the_records_dtype_and_the_torch_graph_gets_float32():
    """The bench's windows are a copy in the records' dtype (float32 from shards: half the
    bytes of float64), and its torch pass feeds the float32 graph float32 whatever
    the windows' dtype (float64 windows of fresh records met a float32 DFT matmul: the main
    job's texture bench failed on it)."""
    rng = np.random.default_rng(2)
    t = np.tile(np.eye(2, dtype=complex), (3, 1, 1, 1))
    records = {"e": rng.standard_normal((3, 1024)).astype(np.float32),
               "i": rng.standard_normal((3, 1024)).astype(np.float32), "t": t}
    e, i, owner, t_cut = _cut(records, 256 / RATE, RATE)
    assert e.dtype == i.dtype == np.float32 and e.shape == (12, 256)
    np.testing.assert_array_equal(owner, np.repeat(np.arange(3), 4))
    np.testing.assert_array_equal(e[5], records["e"][1, 256:512])
    bands = BandPowers(RATE, 64)

    def graph(e, i, t_re, t_im):  # a float32 module, with the decoder's outputs' layout
        power = bands(e)
        n = len(e)
        return power[:, 0], power[:, 0], torch.softmax(power[:, :5], 1), torch.ones(n, dtype=bool)

    for windows in (e, e.astype(np.float64)):
        out = _torch(graph)(windows, i, t_cut)
        expected = bands(torch.tensor(e)).numpy()[:, 0]
        np.testing.assert_allclose(out["grain"], expected, rtol=1e-6)


def test_fidelity_figure_5_22_is_a_line_through_the_origin():
    """The thesis's pipeline on 15 wall positions: measured against actual location is the
    identity line up to the 1 % calibration error and the probe's peaks (thesis R² 0.9981)."""
    from wtml.fidelity import figure_5_22

    r = figure_5_22(load_scene("configs/scenes/onset.yaml"), repeats=1)
    assert r["found"] == 15
    assert r["r2"] > 0.95 and abs(r["slope"] - 1) < 0.1
    assert r["rmse"] < 0.1 * np.ptp(r["actual"])


def _answers(draws: int, seed: int = 0) -> tuple[dict, dict]:
    """Answers shaped as :func:`wtml.bench.texture.oracles` gives them (its fits take 10-25 s
    whatever the draws: early stopping only from 10⁴)."""
    rng = np.random.default_rng(seed)
    out = []
    for extra in ({}, {"sweep_mm": [4.52, 4.16, 3.49, 2.97, 2.70]}):
        y, pred = rng.integers(0, 5, draws), rng.integers(0, 5, draws)
        out.append({"accuracy": float(np.mean(y == pred)), "confusion": confusion(y, pred, 5),
                    "n": draws} | extra)
    return out[0], out[1]


def test_the_oracles_kept_ahead_are_read_back_as_computed(scene, tmp_path, monkeypatch):
    """The main job's warm-up computes the bench's oracles ahead into a file
    (``cached_oracles``): the bench reads back exactly the answers :func:`oracles` gave (the
    confusion as counts again), and computes them again, replacing the file, for another
    scene, other draws, a file that is not strict JSON or whose answers are not valid."""
    import json

    from wtml.bench import texture as bench

    path, direct, calls = tmp_path / "oracles.json", _answers(300), []
    monkeypatch.setattr(bench, "oracles", lambda s, n: calls.append(n) or direct)
    kept = bench.cached_oracles(scene, 300, path)
    assert calls == [300]
    for got in (kept, bench.cached_oracles(scene, 300, path)):  # the second from the file
        for a, b in zip(got, direct, strict=True):
            assert a.keys() == b.keys() and a["accuracy"] == b["accuracy"]
            np.testing.assert_array_equal(a["confusion"], b["confusion"])
            assert isinstance(a["confusion"], np.ndarray)
    assert calls == [300] and kept[1]["sweep_mm"] == direct[1]["sweep_mm"]
    calls.clear()
    data = json.loads(path.read_text())
    bad = {"draws": data | {"draws": 301},
           "scene": data | {"scene_hash": "0" * 64},
           "accuracy": data | {"oracle": data["oracle"] | {"accuracy": 1.5}},
           "counts": data | {"grain_oracle": data["grain_oracle"] | {"n": 299}},
           "negative": data | {"oracle": data["oracle"] | {"confusion": (
               -np.array(data["oracle"]["confusion"])).tolist()}},
           "shape": data | {"oracle": data["oracle"] | {"confusion": [[1, 2], [3, 4]]}},
           "float counts": data | {"oracle": data["oracle"] | {"confusion": [
               [float(x) for x in row] for row in data["oracle"]["confusion"]]}},
           "bool accuracy": data | {"oracle": data["oracle"] | {"accuracy": False}},
           "accuracy not the trace": data | {"oracle": data["oracle"] | {
               "accuracy": data["oracle"]["accuracy"] + 1e-3}},
           "no sweep": data | {"grain_oracle": {k: v for k, v in data["grain_oracle"].items()
                                                if k != "sweep_mm"}},
           "other code": data | {"code": "0" * 64},
           "missing": {k: v for k, v in data.items() if k != "grain_oracle"}}
    for name, contents in [*bad.items(), ("not json", None)]:
        path.write_text("{" if contents is None else json.dumps(contents))
        bench.cached_oracles(scene, 300, path)
        assert calls == [300], name
        assert json.loads(path.read_text()) == data, name  # replaced by the answer computed
        calls.clear()
    bench.cached_oracles(dataclasses.replace(scene, seed=scene.seed + 1), 300, path)
    assert calls == [300]


def test_a_bench_waits_for_the_oracles_the_warm_up_is_computing(scene, tmp_path, monkeypatch):
    """With the file's lock held (the warm-up computing), the bench's ``cached_oracles``
    waits, then reads what the holder wrote instead of computing its own."""
    import fcntl
    import json
    import threading
    import time

    from wtml.bench import texture as bench

    path, answers = tmp_path / "oracles.json", _answers(200)
    monkeypatch.setattr(bench, "oracles", lambda s, n: pytest.fail("computed again"))
    got = []
    with open(tmp_path / "oracles.json.lock", "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        reader = threading.Thread(target=lambda: got.append(
            bench.cached_oracles(scene, 200, path)))
        reader.start()
        time.sleep(0.3)
        assert reader.is_alive() and not got
        path.write_text(json.dumps(bench.oracle_key(scene, 200) | {
            "oracle": bench._listed(answers[0]), "grain_oracle": bench._listed(answers[1])}))
        fcntl.flock(held, fcntl.LOCK_UN)
    reader.join(10)
    assert got and got[0][0]["accuracy"] == answers[0]["accuracy"]
    np.testing.assert_array_equal(got[0][1]["confusion"], answers[1]["confusion"])
