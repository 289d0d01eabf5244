"""The fluid slice at its default size: the issue's accuracy targets that the physics allows.

Slow (about a minute and a half on 2 cores): ``pytest -m slow``. It generates the shipped
scene (its devices drawn from the shipped spread, each record with its own calibrated T),
trains ``configs/fluid.yaml`` as shipped, and checks on the test shard that the
decoder's median ρ error is <= 0.5 %, that it is at least 2x better than the thesis's closed
form in η and in ρ, and that it is within 1.3x of the best achievable, the Bayes posterior
mean under the scene's prior, noise and calibration error (README: 1.12x in η, 1.22x in ρ).
The 1 % η target is out of reach of any estimator here: the Bayes estimate itself has ~2.5 %.
"""

import numpy as np
import pytest
from conftest import generate_and_train

from wtml.baselines import ClassicalFluid
from wtml.baselines.fluid_bayes import BayesFluid
from wtml.bench.accuracy import relative_errors
from wtml.data import load_shards
from wtml.decoders.fluid import TorchFluid, load_fluid_net


@pytest.mark.slow
def test_default_fluid_training_meets_the_reachable_targets(tmp_path):
    scene = generate_and_train(tmp_path, "configs/scenes/fluid.yaml", "configs/fluid.yaml")
    net, _ = load_fluid_net(str(tmp_path / "runs/fluid/checkpoints/last.ckpt"))
    test = load_shards(tmp_path / "data", [scene.shards - 1])
    med = {}
    for p in (TorchFluid(net), ClassicalFluid(scene.excitation.omega, scene.sphere.radius)):
        err = relative_errors(p.predict(test["ze"], test["t"]), test["eta"], test["rho"])
        med[p.name] = {k: float(np.median(v)) for k, v in err.items()}
    dec, cla = med["decoder torch"], med["thesis closed form numpy"]
    assert dec["rho"] <= 0.005
    assert dec["eta"] * 2 <= cla["eta"] and dec["rho"] * 2 <= cla["rho"]
    best = {k: float(np.median(v)) for k, v in relative_errors(
        BayesFluid(scene).predict(test["ze"], test["t"]), test["eta"], test["rho"]).items()}
    assert dec["eta"] <= 1.3 * best["eta"] and dec["rho"] <= 1.3 * best["rho"]
