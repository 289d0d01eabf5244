"""Signals: phasor estimators, analytic signals, band splitting, bridge, noise models, and the
end-to-end check that sampled e(t), i(t) through a known T give back Ze, F, V to the noise."""

import numpy as np
import pytest

from tests.conftest import MACRO
from wtml.physics import drive_voltage, mechanical_from_electrical, ze_from_zm
from wtml.physics.loads import CantileverPoint
from wtml.signals import (
    analytic_fft,
    analytic_fir,
    bridge_channels,
    complex_noise,
    drift_ramp,
    gain_phase_drift,
    impedance_from_bridge,
    multitone,
    phasor_fft,
    phasor_lsq,
    quantize,
    sample_times,
    split_bands,
    sweep,
    tone,
    white_noise,
)

FS = 10_000.0


def test_phasor_estimators_exact_on_clean_tones():
    t = sample_times(1.0, FS)
    x = tone(t, 36.0, 2.5, 0.7)
    np.testing.assert_allclose(phasor_fft(x, FS, 36.0), 2.5 * np.exp(0.7j), rtol=1e-12)
    # a non-integer number of periods: the FFT leaks, the sine fit does not
    t2 = sample_times(0.1234, FS)
    x2 = tone(t2, 36.0, 2.5, 0.7) + 0.3
    np.testing.assert_allclose(phasor_lsq(x2, t2, 36.0), 2.5 * np.exp(0.7j), rtol=1e-10)
    assert abs(phasor_fft(x2, FS, 36.0) - 2.5 * np.exp(0.7j)) > 0.05
    batch = np.stack([x, 2 * x])
    np.testing.assert_allclose(phasor_lsq(batch, t, 36.0), [2.5 * np.exp(0.7j), 5 * np.exp(0.7j)])


def test_multitone_and_sweep():
    t = sample_times(2.0, FS)
    x = multitone(t, [1.0, 420.0], [9.5, 0.02])
    np.testing.assert_allclose(phasor_lsq(x, t, 420.0), 0.02, atol=1e-12)
    s = sweep(t, 90.0, 120.0, 3.0)
    assert s.shape == t.shape and np.isclose(np.abs(s).max(), 3.0, rtol=1e-3)
    # instantaneous frequency from the analytic signal runs 90 -> 120 Hz
    inst = np.diff(np.unwrap(np.angle(analytic_fft(s)))) * FS / (2 * np.pi)
    np.testing.assert_allclose(inst[2000:-2000], np.linspace(90, 120, t.size - 1)[2000:-2000],
                               atol=0.2)
    with pytest.raises(ValueError, match="method"):
        sweep(t, 90.0, 120.0, method="cubic")


def test_analytic_signals_fft_and_causal_fir():
    t = sample_times(1.0, FS)
    x = tone(t, 420.0, 1.0, 0.3)
    np.testing.assert_allclose(analytic_fft(x), np.exp(1j * (2 * np.pi * 420 * t + 0.3)),
                               atol=1e-10)
    z, delay = analytic_fir(x, numtaps=201)
    expected = np.exp(1j * (2 * np.pi * 420 * (t - delay / FS) + 0.3))
    steady = slice(400, None)
    # a 201-tap Blackman Hilbert filter is flat to ~1e-4 well inside the band
    np.testing.assert_allclose(z[steady], expected[steady], atol=2e-3)
    with pytest.raises(ValueError, match="odd"):
        analytic_fir(x, numtaps=100)


def test_band_split_is_complementary_with_equal_delay():
    t = sample_times(4.0, FS)
    x = multitone(t, [1.0, 420.0], [9.5, 0.02], [0.0, 0.4])
    low, high, delay = split_bands(x, FS, cutoff=100.0, numtaps=2001)
    np.testing.assert_allclose(low + high, np.concatenate([np.zeros(delay), x[:-delay]]),
                               atol=1e-12)
    steady = slice(2 * 2001, None)
    td = t[steady] - delay / FS
    np.testing.assert_allclose(high[steady], 0.02 * np.cos(2 * np.pi * 420 * td + 0.4),
                               atol=2e-4)
    np.testing.assert_allclose(low[steady], 9.5 * np.cos(2 * np.pi * 1.0 * td), rtol=0,
                               atol=2e-3)


def test_bridge_round_trip_and_errors():
    ze = 3.2e5 - 1.1e6j
    e = 10.0 * np.exp(0.2j)
    vx, vr = bridge_channels(e, e / ze, range_resistor=1e5)
    np.testing.assert_allclose(impedance_from_bridge(vx, vr, 1e5), ze, rtol=1e-14)
    with pytest.raises(ValueError, match="no current"):
        impedance_from_bridge(vx, 0.0, 1e5)
    with pytest.raises(ValueError, match="range_resistor"):
        bridge_channels(e, 1.0, -5.0)


def test_noise_models(rng):
    x = tone(sample_times(1.0, FS), 50.0)
    noisy = white_noise(np.tile(x, (200, 1)), snr_db=40.0, rng=rng)
    snr = 10 * np.log10(np.mean(x**2) / np.mean((noisy - x) ** 2))
    assert abs(snr - 40.0) < 0.1
    q = quantize(np.linspace(-2, 2, 10001), bits=12, full_scale=1.0)
    step = 2 / 2**12
    inside = np.abs(np.linspace(-2, 2, 10001)) < 1 - step
    assert np.max(np.abs(q - np.linspace(-2, 2, 10001))[inside]) <= step / 2 + 1e-15
    assert q.max() == 1.0 - step and q.min() == -1.0  # clipped to the codes
    with pytest.raises(ValueError, match="bits"):
        quantize(x, bits=1, full_scale=1.0)
    z = complex_noise(np.ones(200_000), 1e-3, rng)
    assert abs(np.std(z) / 1e-3 - 1) < 0.01 and abs(np.mean(z) - 1) < 1e-5
    g, p = drift_ramp(np.linspace(0, 10, 11), 0.01, 0.02)
    np.testing.assert_allclose(gain_phase_drift(1.0 + 0j, g[-1], p[-1]), 1.01 * np.exp(0.02j))


def test_sampled_signals_reproduce_ze_f_v_to_the_noise_level(rng):
    """e(t), i(t) of the macro WT against a cantilever load, sampled at 10 kHz for 1 s with
    white noise at 60 dB SNR on each channel and a 16-bit ADC; the least-squares phasors give
    Ze, F and V within 5 standard errors of the noise: a phasor fitted to N samples with
    noise σ has a standard error σ·sqrt(2/N) per unit amplitude."""
    f0, omega = 36.0, 2 * np.pi * 36.0
    t_mat = MACRO.transduction_matrix(np.array(omega))
    zm = CantileverPoint(82e-3, 1e-3, 0.3e-3, 75e-3).impedance(omega)
    e_ph = 10.0 + 0j
    f_true, v_true, i_ph = drive_voltage(t_mat, zm, e_ph)
    t = sample_times(1.0, FS)
    rr = 1e5  # bridge range resistor: the current channel reads Rr·I
    vx, vr = bridge_channels(tone(t, f0, abs(e_ph), np.angle(e_ph)),
                             tone(t, f0, abs(i_ph), np.angle(i_ph)), rr)
    snr_db = 60.0
    vx_m = quantize(white_noise(vx, snr_db, rng), 16, 12.0)
    vr_m = quantize(white_noise(vr, snr_db, rng), 16, 1.2 * np.abs(vr).max())
    e_est, vr_est = phasor_lsq(vx_m, t, f0), phasor_lsq(vr_m, t, f0)
    i_est = vr_est / rr
    rel_se = 10 ** (-snr_db / 20) / np.sqrt(2) * np.sqrt(2 / t.size)  # σ = A/(√2·10^(SNR/20))
    ze_est = impedance_from_bridge(e_est, vr_est, rr)
    ze_true = ze_from_zm(t_mat, zm)
    assert abs(ze_est / ze_true - 1) < 5 * np.sqrt(2) * rel_se
    f_est, v_est = mechanical_from_electrical(t_mat, e_est, i_est)
    # F and V: the same errors carried through the matrix, bounded term by term
    for est, true, (a, b) in ((f_est, f_true, (t_mat[1, 1] * e_ph, t_mat[0, 1] * i_ph)),
                              (v_est, v_true, (t_mat[1, 0] * e_ph, t_mat[0, 0] * i_ph))):
        assert abs(est - true) < 5 * rel_se * (abs(a) + abs(b))
        assert abs(est - true) > 0  # the noise reached it


def test_lead_in_starts_from_rest_and_its_rate_is_the_derivative():
    from wtml.signals.excitation import lead_in

    t = np.arange(-20000, 5000) / 20000.0  # 1 s lead-in at 20 kS/s
    e, de = np.sin(2 * np.pi * 7 * t), 2 * np.pi * 7 * np.cos(2 * np.pi * 7 * t)
    er, der = lead_in(t, e, de, 1.0)
    assert er[0] == 0 and der[0] == 0
    np.testing.assert_array_equal(er[t >= 0], e[t >= 0])
    np.testing.assert_allclose(der[t >= 0], de[t >= 0], rtol=0, atol=1e-12)  # sin(π) = 1e-16
    np.testing.assert_allclose(np.gradient(er, t)[1:-1], der[1:-1], atol=2e-3 * np.abs(de).max())
    with pytest.raises(ValueError, match="lead_s"):
        lead_in(t, e, de, 0.0)
