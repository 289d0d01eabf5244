"""sbi's neural posterior estimation on the fluid scene (issue 25 §4), beside the decoder in
``wtml bench coverage``: a small budget, its TARP and credible-interval coverage. Needs the
optional ``[sbi]`` extra; skipped without it."""

import numpy as np
import pytest

pytestmark = pytest.mark.slow

sbi = pytest.importorskip("sbi")


def test_npe_on_the_fluid_scene_is_scored_by_tarp_and_by_credible_intervals():
    from conftest import FLUID_SMALL

    from wtml.bench.sbi_fluid import credible_hits, features, run_npe

    test = FLUID_SMALL.simulate(300, np.random.default_rng(3))
    x = features(test["ze"], test["t"], 0.01 * FLUID_SMALL.reference_zm())
    assert x.shape == (300, 2 * FLUID_SMALL.excitation.n_freq) and np.isfinite(x).all()
    result = run_npe(FLUID_SMALL, test, simulations=3000, max_epochs=20, seed=1)
    s = result["summary"]
    assert s["simulations"] == 3000 and s["tarp_records"] == 300
    assert -0.5 <= s["tarp_atc"] <= 0.5 and 0.0 <= s["tarp_ks_p"] <= 1.0
    for name in ("eta", "rho"):
        hits = result["rows"][name][0]["hits"]
        assert hits.shape == (300, 2) and set(np.unique(hits)) <= {0.0, 1.0}
        # a 95 % interval holds at least what its 68 % one does, for every record
        assert (hits[:, 1] >= hits[:, 0]).all() and hits[:, 1].mean() > 0.5
    # credible intervals of exact posterior draws cover at their nominal rates
    rng = np.random.default_rng(0)
    truth, samples = rng.normal(size=4000), rng.normal(size=(400, 4000))
    np.testing.assert_allclose(credible_hits(samples, truth).mean(0), [0.6827, 0.95],
                               atol=0.02)
