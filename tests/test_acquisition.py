"""A real acquisition (physics.md §12): each effect's generated noise against its stated
density or level, the switches, the errors, and the scenes' bench-top records."""

import dataclasses

import numpy as np
import pytest
from scipy.signal import welch
from scipy.stats import kstest

from tests.conftest import ROOT
from wtml.constants import BOLTZMANN
from wtml.physics.spread import DeviceSpread
from wtml.scenes import load_scene
from wtml.scenes.onset import OnsetScene
from wtml.scenes.texture import TextureScene
from wtml.schema import SceneError, build
from wtml.signals.acquisition import (
    AcquisitionEffects,
    IVConverter,
    base_motion,
    coloured_noise,
    mains_hum,
)

RATE = 26880.0
BENCH = AcquisitionEffects().only(*AcquisitionEffects.NAMES[:-1])  # all but the base


def psd(x, rate, nperseg=4096):
    """Welch's one-sided PSD averaged over records: f (Hz), unit²/Hz."""
    f, p = welch(x, fs=rate, nperseg=nperseg, axis=-1)
    return f, p.mean(0)


def test_johnson_noise_of_the_feedback_resistor_has_its_rms_over_the_band():
    """sqrt(4kT/R_f): 0.13 pA/sqrt(Hz) at 1 MΩ (physics.md §12), ~15 pA over 13 kHz; the
    generated noise's rms over the band to 2 %."""
    iv = IVConverter(enabled=True, feedback_ohm=1e6, current_noise=0.0, voltage_noise=0.0)
    density = iv.density(np.array([1.0, 1e3]), 0.7e-9)
    np.testing.assert_allclose(np.sqrt(density), np.sqrt(4 * BOLTZMANN * 296.0 / 1e6))
    assert 0.125e-12 < np.sqrt(density[0]) < 0.13e-12
    fx = AcquisitionEffects(iv=iv)
    x = fx.current_noise((32, 8192), RATE, 0.7e-9, 1e-6, np.random.default_rng(0))
    want = np.sqrt(density[0] * RATE / 2)  # ≈ 15 pA over 13.4 kHz
    assert 14e-12 < want < 16e-12
    assert abs(x.std() / want - 1) < 0.02


def test_op_amp_current_noise_shows_its_1_over_f_corner():
    """i_n² (1 + f_c/f): the measured PSD is i_n² well above the corner, twice that at it and
    eleven times at a tenth of it (10 %)."""
    iv = IVConverter(enabled=True, feedback_ohm=1e12, current_noise=1e-13, corner_hz=30.0,
                     voltage_noise=0.0)
    rate = 1000.0
    x = coloured_noise(lambda f: iv.density(f, 0.0), (16, 2**16), rate,
                       np.random.default_rng(1))
    f, p = psd(x, rate, nperseg=8192)
    for at, factor in ((3.0, 11.0), (30.0, 2.0), (300.0, 1.1)):
        near = (f > at * 0.9) & (f < at * 1.1)
        want = 1e-26 * factor + 4 * BOLTZMANN * 296.0 / 1e12
        assert abs(p[near].mean() / want - 1) < 0.1, (at, p[near].mean() / want)


def test_op_amp_voltage_noise_through_cp_grows_with_frequency():
    """e_n across the transducer's capacitance: e_n² (1/R_f² + (ωCp)²), measured at 100 Hz,
    1 kHz and 10 kHz (10 %): two decades of f, four of density."""
    cp = 0.72e-9
    iv = IVConverter(enabled=True, feedback_ohm=1e7, current_noise=0.0, voltage_noise=5.1e-9)
    x = coloured_noise(lambda f: iv.densities(f, cp)["voltage"], (16, 2**15), RATE,
                       np.random.default_rng(2))
    f, p = psd(x, RATE)
    for at in (100.0, 1e3, 1e4):
        near = (f > at * 0.95) & (f < at * 1.05)
        want = 5.1e-9**2 * (1e-14 + (2 * np.pi * f[near] * cp) ** 2)
        assert abs(np.mean(p[near] / want) - 1) < 0.1, at


def test_adc_floor_at_its_dynamic_range_on_both_channels():
    """118 dB below a full-scale sine: rms FS/√2 · 10^(-118/20), white, on each channel."""
    fx = AcquisitionEffects().only("adc")
    rng = np.random.default_rng(3)
    i = fx.current_noise((8, 2**15), RATE, 0.7e-9, 1e-6, rng)
    e = fx.voltage_noise((8, 2**15), RATE, 10.0, rng)
    for x, fs in ((i, 1e-6), (e, 10.0)):
        want = fs / np.sqrt(2) * 10 ** (-118 / 20)
        assert abs(x.std() / want - 1) < 0.01
        f, p = psd(x, RATE)
        lo, hi = p[(f > 100) & (f < 1000)].mean(), p[(f > 1e4) & (f < 1.3e4)].mean()
        assert abs(lo / hi - 1) < 0.1  # white


def test_mains_hum_at_its_harmonics_level_and_random_phase():
    """The hum's lines at h × 50 Hz with amplitude level × full scale × a_h (exact over whole
    mains periods), nothing elsewhere, and a phase uniform over records."""
    fx = AcquisitionEffects().only("hum")
    amps = 1e-6 * fx.hum.amplitudes()
    n = int(RATE / 50 * 20)  # 20 mains periods
    x = fx.current_noise((400, n), RATE, 0.7e-9, 1e-6, np.random.default_rng(4))
    spec = 2 * np.fft.rfft(x, axis=-1) / n
    f = np.fft.rfftfreq(n, 1 / RATE)
    lines = np.round(50.0 * np.arange(1, len(amps) + 1) / (f[1] - f[0])).astype(int)
    np.testing.assert_allclose(np.abs(spec[:, lines]), np.broadcast_to(amps, (400, 5)),
                               rtol=1e-9)
    others = np.delete(np.abs(spec), lines, axis=1)
    assert others.max() < 1e-9 * amps[0]
    phase = np.angle(spec[:, lines])
    assert np.all(np.abs(np.mean(np.exp(1j * phase), 0)) < 0.15)  # uniform: |mean| ~ 0.05
    assert kstest((phase[:, 0] + np.pi) / (2 * np.pi), "uniform").pvalue > 1e-3
    with pytest.raises(ValueError, match="mains_hz must be in"):
        mains_hum(60.0, np.ones(30), (1, 100), 2000.0, np.random.default_rng(0))


def test_dac_error_and_coupling_drift_per_record():
    """The drive's amplitude factor 1 + N(0, 0.1 %) and the coupling's 1 + d31'·N(0, ΔT), one
    per record: normal, with the stated std (3 %) and mean (3 standard errors)."""
    rng = np.random.default_rng(5)
    n = 20000
    for draw, sigma in ((BENCH.drive_scale, 1e-3), (BENCH.coupling_scale, 2e-3 * 1.0)):
        x = draw(n, rng)
        assert abs(x.mean() - 1) < 3 * sigma / np.sqrt(n)
        assert abs(x.std() / sigma - 1) < 0.03
        assert kstest((x - 1) / sigma, "norm").pvalue > 1e-3
    off = AcquisitionEffects()
    before = rng.bit_generator.state
    np.testing.assert_array_equal(off.drive_scale(5, rng), np.ones(5))
    np.testing.assert_array_equal(off.coupling_scale(5, rng), np.ones(5))
    assert np.all(off.current_noise((2, 64), RATE, 1e-9, 1e-6, rng) == 0)
    assert rng.bit_generator.state == before  # an effect switched off draws nothing


def test_base_motion_has_its_rms_in_its_band_only():
    """x_b(t): the stated rms (2 %: five standard errors over 245 × 64 frequencies), no power
    outside the band, and physics.md §12's example: 0.8 µm rms near 10 Hz is 50 µm/s rms
    (8 %: five standard errors over 17 × 64)."""
    rate = 1000.0
    x = base_motion(0.8e-6, (5.0, 20.0), (64, 2**14), rate, np.random.default_rng(6))
    assert x.shape == (64, 2**14)
    assert abs(x.std() / 0.8e-6 - 1) < 0.02
    spec = np.abs(np.fft.rfft(x, axis=-1)) ** 2
    f = np.fft.rfftfreq(x.shape[-1], 1 / rate)
    outside = (f < 5.0) | (f > 20.0)
    assert spec[:, outside].sum() < 1e-20 * spec.sum()
    x = base_motion(0.8e-6, (9.5, 10.5), (64, 2**14), rate, np.random.default_rng(6))
    speed = np.gradient(x, 1 / rate, axis=-1).std()
    assert abs(speed / 50e-6 - 1) < 0.08
    with pytest.raises(ValueError, match="band_hz must be in"):
        base_motion(1e-6, (5.0, 600.0), (1, 1000), rate, np.random.default_rng(0))
    with pytest.raises(ValueError, match="holds none"):
        base_motion(1e-6, (5.0, 5.01), (1, 100), rate, np.random.default_rng(0))
    fx = AcquisitionEffects().only("base")
    assert fx.base_motion(2, 4096, rate, np.random.default_rng(0)).std() > 0


@pytest.mark.parametrize(("data", "message"), [
    ({"hum": {"mains_hz": 55.0}}, r"acquisition.effects.hum.mains_hz: must be 50 or 60"),
    ({"iv": {"feedback_ohm": 0.0}}, r"acquisition.effects.iv.feedback_ohm: must be in"),
    ({"iv": {"enabled": "yes"}}, r"acquisition.effects.iv.enabled: must be true or false"),
    ({"dac": {"amplitude_error": 0.5}}, r"acquisition.effects.dac.amplitude_error: must be in"),
    ({"adc": {"dynamic_range": 118}}, r"acquisition.effects.adc.dynamic_range: unknown key"),
])
def test_out_of_range_effects_are_clear_scene_errors(data, message):
    with pytest.raises(SceneError, match=message):
        build(OnsetScene, {"acquisition": {"effects": data}})
    with pytest.raises(ValueError, match="unknown"):
        AcquisitionEffects().only("hum", "wind")


def test_base_motion_moves_the_onset_wall_and_texture_refuses_it():
    """The onset scene's wall follows x_b(t): at a vanishing rms its records are those of the
    fixed wall (the implicit stepper against the switched one: onsets within a sample), at
    2 µm its onsets move; the texture scene, which cannot follow it, refuses it."""
    base = {"drive": {"cycles": 0.5}, "samples": 4, "shards": 1}
    rate = 26880.0
    onsets = {}
    for rms in (None, 1e-15, 2e-6):
        fx = {"effects": {"base": {"enabled": True, "rms_m": rms}}} if rms else {}
        scene = build(OnsetScene, {**base, "acquisition": fx})
        rec = scene.simulate(4, np.random.default_rng(2), gaps=np.full(4, 6e-6))
        onsets[rms] = rec["onset"][:, 0]
    assert np.all(np.isfinite(onsets[None]))
    np.testing.assert_allclose(onsets[1e-15], onsets[None], atol=1.01 / rate)
    assert np.max(np.abs(onsets[2e-6] - onsets[None])) > 10 / rate
    with pytest.raises(SceneError, match="acquisition.effects.base.enabled: the texture"):
        build(TextureScene, {"acquisition": {"effects": {"base": {"enabled": True}}}})


def test_shipped_scenes_are_bench_top_and_the_probe_band_noise_is_the_budget():
    """The shipped texture and onset scenes switch every effect on but the base (the onset
    decoder removes the mains lines in its graph and fits its touch threshold to the noise,
    tests/test_mains_lines.py; before, the onset scenes trained with every effect off); the
    current channel's
    added noise in 320-520 Hz (the probe band) is the I–V converter's density integrated
    plus the ADC floor's share (10 %), far below the probe's current; the records are the
    same from the same seed."""
    for name in ("onset", "onset_full", "texture", "texture_fepa"):
        fx = load_scene(ROOT / f"configs/scenes/{name}.yaml").acquisition.effects
        off = {"base"}
        assert [getattr(fx, n).enabled for n in fx.NAMES] == [n not in off for n in fx.NAMES]
    scene = dataclasses.replace(load_scene(ROOT / "configs/scenes/onset.yaml"),
                                calibration_error=0.0, spread=DeviceSpread())  # Cp nominal
    a = scene.acquisition
    noisy = dataclasses.replace(scene, acquisition=dataclasses.replace(
        a, effects=a.effects.only("iv", "adc", "hum")))
    ideal = dataclasses.replace(scene, acquisition=dataclasses.replace(
        a, effects=a.effects.only()))
    gaps = np.array([np.nan])
    rec = noisy.simulate(1, np.random.default_rng(7), gaps=gaps)
    again = noisy.simulate(1, np.random.default_rng(7), gaps=gaps)
    np.testing.assert_array_equal(rec["i"], again["i"])
    base = ideal.simulate(1, np.random.default_rng(7), gaps=gaps)
    added = rec["i"].astype(float) - base["i"].astype(float)
    f, p = psd(added, a.sample_rate_hz, nperseg=8192)
    band = (f >= 320) & (f <= 520)
    got = np.sqrt(p[band].sum() * (f[1] - f[0]))
    fb = np.linspace(320, 520, 2001)
    cp = scene.transducer().capacitance
    want = np.sqrt(np.trapezoid(a.effects.iv.density(fb, cp), fb)
                   + a.effects.adc.rms(a.i_full_scale_a) ** 2 * 200 / (a.sample_rate_hz / 2))
    assert abs(got / want - 1) < 0.1, (got, want)
    t = scene.times()
    probe = 2 * np.abs(np.mean(base["i"][0] * np.exp(-2j * np.pi * 420.0 * t)))
    assert probe / np.sqrt(2) / got > 10**4  # > 80 dB in the probe band
    np.testing.assert_array_equal(rec["e"].shape, base["e"].shape)


def test_the_in_place_noise_is_the_textbook_sum_and_leaves_its_inputs_alone():
    """``quantize`` works in its own array (records of a few 100 MB): bit for bit the plain
    expression, the caller's samples untouched; ``mains_hum`` (one matrix product) is the
    plain sum of sines to rounding."""
    from wtml.signals.noise import quantize

    rng = np.random.default_rng(3)
    x = (rng.standard_normal((3, 500)) * 4.0).astype(np.float32)  # past ±2 V: clipped too
    kept = x.copy()
    step = 2 * 2.0 / 2**12
    plain = np.clip(np.round(np.asarray(x, dtype=float) / step), -2**11, 2**11 - 1) * step
    assert np.array_equal(quantize(x, 12, 2.0), plain)
    assert np.array_equal(x, kept)
    x64 = x.astype(float)  # asarray does not copy it: quantize must
    assert np.array_equal(quantize(x64, 12, 2.0), plain)
    assert np.array_equal(x64, kept)
    amps = np.array([1e-3, 4e-5, 3e-4])
    hum = mains_hum(50.0, amps, (3, 500), 5e3, np.random.default_rng(7))
    phase = np.random.default_rng(7).uniform(0, 2 * np.pi, (3, 3))
    t = np.arange(500) / 5e3
    plain = np.zeros((3, 500))
    for h, a in enumerate(amps):
        plain += a * np.sin(2 * np.pi * 50.0 * (h + 1) * t + phase[:, h, None])
    np.testing.assert_allclose(hum, plain, rtol=0, atol=1e-12 * amps.sum())
    assert np.abs(plain).max() > 0.5 * amps.max()  # the tolerance is far below the hum
