"""The texture scene at 204.8 kS/s (configs/scenes/texture_pxi.yaml) against the 51.2 kS/s one,
the band-power peer, and the rate study's pairing (issue 25 §3)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import resample_poly

from wtml.baselines.texture_peers import BandPowerPeer
from wtml.bench.rate_axis import frontier_lines
from wtml.bench.texture_rate import PAIRED, check_paired
from wtml.decoders.texture import BANDS_PER_OCTAVE, band_edges
from wtml.runtime.texture import windows
from wtml.scenes import load_scene

RATES = (51200.0, 204800.0)


def _short(scene):
    """One specimen per grade, 0.5 s records after the scene's own 1 s lead-in."""
    return replace(scene, specimens_per_grade=1, drive=replace(scene.drive, record_s=0.5))


@pytest.fixture(scope="module")
def pair():
    """The same 5 draws (one specimen of each grade) at both rates: ``(records_51k2,
    records_204k8, scene_51k2)``."""
    low = _short(load_scene("configs/scenes/texture.yaml"))
    high = _short(load_scene("configs/scenes/texture_pxi.yaml"))
    return (low.simulate(5, np.random.default_rng(7)), high.simulate(5, np.random.default_rng(7)),
            low)


def _phasor(x: np.ndarray, hz: np.ndarray, rate: float) -> np.ndarray:
    """The fundamental's complex amplitude of each row of ``x`` ``(n, m)`` at ``hz`` ``(n,)``."""
    t = np.arange(x.shape[1]) / rate
    return 2 * np.mean(x * np.exp(-2j * np.pi * hz[:, None] * t), axis=1)


def test_the_pxi_scene_is_the_texture_scene_at_204k8_with_the_same_noise_density():
    low = load_scene("configs/scenes/texture.yaml")
    high = load_scene("configs/scenes/texture_pxi.yaml")
    check_paired(low, high)  # nothing but the acquisition, the oversampling, modes and mesh
    assert (low.n_modes, high.n_modes) == (22, 40)  # each every mode below its Nyquist
    assert (low.whisker_elements, high.whisker_elements) == (32, 64)  # each converged there
    a, b = low.acquisition, high.acquisition
    assert (a.sample_rate_hz, b.sample_rate_hz) == RATES
    ratio = np.sqrt(b.sample_rate_hz / a.sample_rate_hz)  # white noise: rms ∝ sqrt(band)
    assert b.i_noise_a == pytest.approx(a.i_noise_a * ratio)
    assert b.e_noise_v == pytest.approx(a.e_noise_v * ratio)
    assert replace(b, sample_rate_hz=a.sample_rate_hz, i_noise_a=a.i_noise_a,
                   e_noise_v=a.e_noise_v) == a
    # its simulation step is finer than the 51.2 kS/s scene's: every stability bound holds
    assert b.sample_rate_hz * high.oversample >= a.sample_rate_hz * low.oversample


def test_the_same_seed_draws_the_same_specimens_and_nuisance_at_both_rates(pair):
    low, high, _ = pair
    assert low["i"].shape[1] * 4 == high["i"].shape[1]
    for key in PAIRED:
        np.testing.assert_array_equal(low[key], high[key], err_msg=key)
    # the same devices' calibrated T; the 204.8 kS/s model's 18 more modes and its whisker's
    # 64 elements (32 at 51.2 kS/s) move it by 5.2e-5, under a 1 % calibration error
    np.testing.assert_allclose(low["t"], high["t"], rtol=1e-4)


def test_both_rates_record_the_same_physics_below_the_slower_nyquist(pair):
    """The current's fundamental phasor agrees to 5e-4 (measured: 1.6e-4 on these 0.5 s
    records, 6e-5 on 1 s ones: the 51.2 kS/s scene's coarser step and the mains hum, drawn
    anew at each rate, leaking into the 36 Hz bin), the voltage's to 1e-4 (measured 3e-5), and
    the current's power in 1-20 kHz, the faster records decimated to 51.2 kS/s, to 5 %
    (measured: 2.0 %, 1-15 kHz 1.0 %; to 25 kHz 5.7 %, the decimating filter's edge). Each
    scene keeps every mode below its Nyquist, so the grains ring the same modes up to 20 kHz
    at both rates."""
    low, high, scene = pair
    i_low = _phasor(low["i"].astype(float), low["whisk_hz"], RATES[0])
    i_high = _phasor(high["i"].astype(float), high["whisk_hz"], RATES[1])
    np.testing.assert_array_less(np.abs(i_high / i_low - 1), 5e-4)
    e_low = _phasor(low["e"].astype(float), low["whisk_hz"], RATES[0])
    e_high = _phasor(high["e"].astype(float), high["whisk_hz"], RATES[1])
    np.testing.assert_array_less(np.abs(e_high / e_low - 1), 1e-4)
    peer = BandPowerPeer(scene.calibration_hz, RATES[0], top_hz=20000.0)
    p_low = peer.band_powers(low["i"]).sum(1)
    p_high = peer.band_powers(resample_poly(high["i"].astype(float), 1, 4, axis=-1)).sum(1)
    np.testing.assert_array_less(np.abs(np.log(p_high / p_low)), 0.05)


@pytest.mark.parametrize("rate", [*RATES, 96000.0, 20000.0])
def test_bands_are_log_spaced_below_the_nyquist_and_shared_across_rates(rate):
    edges = band_edges(rate)
    assert edges[-1] <= rate / 2 < edges[-1] * 2 ** (1 / BANDS_PER_OCTAVE)
    assert edges[0] <= 1000.0 < edges[1]
    np.testing.assert_allclose(np.diff(np.log2(edges)), 1 / BANDS_PER_OCTAVE)
    slow = band_edges(min(rate, RATES[0]))
    np.testing.assert_allclose(edges[:len(slow)], slow)  # the same bands below both Nyquists
    capped = band_edges(rate, top_hz=12800.0)
    assert capped[-1] == pytest.approx(min(12800.0, edges[-1]))
    with pytest.raises(ValueError, match="must exceed"):
        band_edges(rate, low_hz=rate)


def test_band_power_peer_fits_and_predicts_at_either_rate(pair):
    low, high, scene = pair
    for records, rate in ((low, RATES[0]), (high, RATES[1])):
        (e, i), owner = windows(np.stack([records["e"], records["i"]]), int(0.25 * rate))
        peer = BandPowerPeer(scene.calibration_hz, rate, max_iter=5)
        x = peer.features(e, i, records["t"][owner])
        assert x.shape == (10, len(peer.edges) - 1 + 11) and np.isfinite(x).all()
        assert peer.edges[-1] <= rate / 2
        with pytest.raises(RuntimeError, match="before fit"):
            peer.predict(e, i, records["t"][owner])
        out = peer.fit(e, i, records["t"][owner], records["grade"][owner]).predict(
            e, i, records["t"][owner])
        assert out["grade"].shape == (10,) and set(out["grade"]) <= set(range(5))
        assert np.isnan(out["grain"]).all()
    # at 204.8 kS/s the bands reach 102.4 kHz; restricted, they are the 51.2 kS/s peer's
    wide = BandPowerPeer(scene.calibration_hz, RATES[1])
    cut = BandPowerPeer(scene.calibration_hz, RATES[1], top_hz=RATES[0] / 2)
    np.testing.assert_allclose(cut.edges, BandPowerPeer(scene.calibration_hz, RATES[0]).edges)
    assert wide.edges[-1] == RATES[1] / 2


def test_the_study_refuses_scenes_that_differ_in_more_than_the_acquisition():
    low = load_scene("configs/scenes/texture.yaml")
    with pytest.raises(ValueError, match="reach_m"):
        check_paired(low, replace(low, reach_m=4e-3))
    high = load_scene("configs/scenes/texture_pxi.yaml")
    with pytest.raises(ValueError, match="texture_pxi: n_modes: its 22 modes end at 29169 Hz"):
        check_paired(low, replace(high, n_modes=22))  # below its 102.4 kHz Nyquist


def test_the_rate_study_is_an_axis_of_the_texture_frontier(tmp_path):
    """A study's summary becomes the frontier's rate table: each method's accuracy as the
    study measured it, each rate's features timed here (the lowest rate the unit, side by
    side), the paired differences; without a study, one line saying how to make it."""
    assert "wtml bench texture-rate" in frontier_lines(tmp_path / "none.json")[0]
    methods = [{"name": "51.2 kS/s", "rate_hz": RATES[0], "top_hz": 25600.0,
                "accuracy": 0.89, "interval": [0.86, 0.92]},
               {"name": "204.8 kS/s", "rate_hz": RATES[1], "top_hz": 102400.0,
                "accuracy": 0.894, "interval": [0.87, 0.92]}]
    summary = {"scenes": ["configs/scenes/texture.yaml", "configs/scenes/texture_pxi.yaml"],
               "rates_hz": list(RATES), "window_s": 0.25, "train_specimens": 640,
               "test_specimens": 200, "methods": methods,
               "differences": [{"name": "204.8 kS/s minus 51.2 kS/s", "difference": 0.004,
                                "interval": [-0.01, 0.016]}]}
    path = tmp_path / "summary.json"
    path.write_text(__import__("json").dumps(summary))
    lines = frontier_lines(path, records=1)
    rows = [line for line in lines if line.startswith("| 51.2") or line.startswith("| 204.8")]
    assert len(rows) == 3  # two rates and one paired difference
    assert "| 89.0 [86.0, 92.0] |" in rows[0] and "×1.00 (1.00–1.00)" in rows[0]
    assert "| 102.4 | 89.4 [87.0, 92.0] |" in rows[1]
    ratio = float(rows[1].split("×")[1].split()[0])
    assert ratio > 0 and "| +0.4 [-1.0 to +1.6] |" in rows[2]
