"""Measurement noise models: white noise at an SNR, ADC quantisation, gain and phase drift.

All take a ``numpy.random.Generator`` where they draw, so results are reproducible by seed.
"""

from __future__ import annotations

import numpy as np

from wtml.physics.validation import check_range


def complex_noise(z, relative_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``z (1 + n)`` with ``n`` circular complex Gaussian, ``E|n|² = relative_sigma²``.

    Args:
        z: complex phasors or impedances, any shape.
        relative_sigma: relative standard deviation (e.g. 1e-4 for 0.01 %).
        rng: random generator.
    """
    check_range("relative_sigma", relative_sigma, 0.0, 1.0)
    z = np.asarray(z, dtype=complex)
    n = rng.standard_normal(z.shape + (2,)) @ np.array([1.0, 1j]) / np.sqrt(2)
    return z * (1 + relative_sigma * n)


def white_noise(x, snr_db: float, rng: np.random.Generator) -> np.ndarray:
    """Add white Gaussian noise to a real signal at a signal-to-noise ratio.

    Args:
        x: real samples, shape ``(..., n_samples)``; the SNR is per signal (last axis),
            against its mean-square value.
        snr_db: 10 log10(signal power / noise power), in dB.
        rng: random generator.
    """
    x = np.asarray(x, dtype=float)
    power = np.mean(x**2, axis=-1, keepdims=True)
    sigma = np.sqrt(power / 10 ** (snr_db / 10))
    return x + sigma * rng.standard_normal(x.shape)


def quantize(x, bits: int, full_scale: float) -> np.ndarray:
    """An ideal ADC: clip to ``[-full_scale, full_scale]`` and round to ``bits`` bits.

    Args:
        x: real samples in the input unit (V), any shape.
        bits: resolution, 2–32.
        full_scale: the positive full-scale input (V), > 0.

    Returns:
        The quantised samples, same unit and shape. Step ``2 full_scale / 2**bits``.
    """
    check_range("bits", bits, 2, 32)
    check_range("full_scale", full_scale, 0.0, np.inf, low_open=True, high_open=True)
    step = 2 * full_scale / 2**bits
    levels = np.asarray(x, dtype=float) / step  # a new array: the rest works in it
    np.round(levels, out=levels)
    np.clip(levels, -(2 ** (bits - 1)), 2 ** (bits - 1) - 1, out=levels)
    levels *= step
    return levels


def gain_phase_drift(z, gain_error, phase_error_rad) -> np.ndarray:
    """A channel's gain and phase error on a phasor: ``z (1 + g) e^{jθ}``.

    Args:
        z: complex phasors, any shape.
        gain_error: relative gain error g, broadcastable (e.g. linear in time for a drift).
        phase_error_rad: phase error θ in rad, broadcastable.
    """
    return np.asarray(z) * (1 + np.asarray(gain_error)) * np.exp(1j * np.asarray(phase_error_rad))


def drift_ramp(t, total_gain: float, total_phase_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear drift over a record: gain and phase errors growing from 0 to the totals.

    Args:
        t: sample times in s, shape ``(n,)``.
        total_gain: relative gain error reached at the last sample.
        total_phase_rad: phase error reached at the last sample, in rad.

    Returns:
        ``(gain_error, phase_error_rad)``, each shape ``(n,)``, for :func:`gain_phase_drift`
        on an analytic signal.
    """
    t = np.asarray(t, dtype=float)
    frac = (t - t[0]) / (t[-1] - t[0]) if t.size > 1 else np.zeros_like(t)
    return total_gain * frac, total_phase_rad * frac
