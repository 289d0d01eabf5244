"""`wtml bench device` (issue 23 §4), small: its rows, and the physics it rests on."""

import json

import numpy as np

from wtml.bench.device import (
    FREE,
    TRUTH,
    WHISKER_LOSS,
    measurements,
    run_device_bench,
    truth_device,
)
from wtml.devices import load_device
from wtml.physics.beam_presets import build
from wtml.physics.identify import free_ze


def test_the_hidden_device_file_is_the_hidden_beam():
    """The true device as a file (its whisker's own loss included) builds the beam the bench
    measures: the bench's truth is a device a user could have written."""
    device, beam = truth_device(load_device("micro"))
    omega = 2 * np.pi * np.geomspace(250, 3500, 50)
    np.testing.assert_allclose(free_ze(build(device), omega), free_ze(beam, omega), rtol=1e-12)
    assert device.losses.whisker == 0.02 * TRUTH["loss_factor"] * WHISKER_LOSS
    m = measurements(beam, "sweep + HUE(0) + 3 pins", 1e-4, np.random.default_rng(0))
    assert len(m.contacts) == 3 and m.hue0 > 0


def test_the_bench_reports_every_set_against_the_true_device_decoder(tmp_path):
    report = run_device_bench(tmp_path, samples=1800, epochs=2, test_records=200,
                              noises=(1e-4,), sets=("sweep + HUE(0) + 3 pins",))
    assert "| the true device itself |" in report and "| sweep + HUE(0) + 3 pins | 0.0001 |" \
        in report
    rows = json.loads((tmp_path / "summary.json").read_text())
    assert [r["set"] for r in rows] == ["the true device itself", "sweep + HUE(0) + 3 pins"]
    fitted = rows[1]
    # with pins at 1e-4 every parameter is identified, near the truth; the physics
    # inversion on the fitted device's model finds the true device's contacts to ~1 µm
    assert fitted["unidentifiable"] == [] and 0.7 < fitted["reduced_chi2"] < 1.3
    for name in TRUTH:
        assert abs(fitted["factors"][name] / TRUTH[name] - 1) < 1e-3, name
    assert abs(fitted["factors"]["whisker.loss_factor"] / WHISKER_LOSS - 1) < 1e-2
    assert set(fitted["factors"]) == set(FREE)
    assert fitted["inversion"] < 3.0
    assert all(np.isfinite(r["decoder"]) for r in rows)
