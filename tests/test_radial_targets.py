"""The radial slice at its default size: issue 21's targets for our decoder over the device
spread.

Slow (several minutes on 2 cores): ``pytest -m slow``. It generates the shipped scene (each
record's device drawn from the manufacturing spread, with its free reference), trains
``configs/radial.yaml`` as shipped, and checks on the first 10000 test samples (devices the
training never saw): RMSE ≤ 5 µm (the thesis's ANN: 5.4 µm on its real device) and
|error| ≤ 2σ for at least 90 % of the answers; and, on fresh records of the nominal device,
that the decoder is at least 5× below the best 9th-degree polynomial there (the thesis:
4.8×). With the whisker's modulus ±3 %, thickness and length ±0.5 % the first target is
beyond what the free reference can tell (the bench's device-spread table: the whisker's
parameters alone cost 15–24 µm): this test states the issue's target, not a promise.
"""

import numpy as np
import pytest
from conftest import generate_and_train

from wtml.baselines.radial import PolynomialRadial
from wtml.data import load_shards
from wtml.decoders.radial import TorchRadial, load_radial_net


@pytest.mark.slow
def test_default_radial_decoder_meets_the_targets(tmp_path):
    scene = generate_and_train(tmp_path, "configs/scenes/radial.yaml", "configs/radial.yaml")
    net, _ = load_radial_net(str(tmp_path / "runs/radial/checkpoints/last.ckpt"))
    decoder = TorchRadial(net)
    train = load_shards(tmp_path / "data", list(range(scene.shards - 2)))
    test = {k: v[:10000] for k, v in load_shards(tmp_path / "data", [scene.shards - 1]).items()}
    out = decoder.predict(test["ze"], test["ref"])
    err = out["distance"] - test["distance"]
    assert np.mean(np.abs(err) <= 2 * out["sigma"]) >= 0.9
    nominal = scene.simulate(10000, np.random.default_rng(9), widths={})
    ours = decoder.predict(nominal["ze"], nominal["ref"])["distance"] - nominal["distance"]
    best_poly = min(
        np.sqrt(np.mean((PolynomialRadial(part).fit(train["ze"], train["ref"], train["distance"])
                         .predict(nominal["ze"], nominal["ref"])["distance"]
                         - nominal["distance"]) ** 2))
        for part in ("real", "imag"))
    assert best_poly >= 5 * np.sqrt(np.mean(ours**2))
    assert np.sqrt(np.mean(err**2)) <= 5e-6
