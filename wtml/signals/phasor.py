"""Phasors of steady tones: ``x(t) = Re(X e^{jωt})`` -> complex amplitude ``X``.

Two estimators (thesis Eq. 4.8 and a lock-in): the FFT peak, exact when the record holds a
whole number of periods, and a least-squares sine fit at the known frequency, robust to
leakage and to records of any length.
"""

from __future__ import annotations

import numpy as np

from wtml.physics.validation import check_range


def phasor_fft(x, sample_rate: float, frequency: float) -> np.ndarray:
    """Complex amplitude at the FFT bin nearest ``frequency``.

    Args:
        x: real samples, shape ``(..., n)``.
        sample_rate: Hz.
        frequency: Hz, below Nyquist.

    Returns:
        shape ``(...)``: ``2 X[k] / n`` (amplitude and phase of the cosine).
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    check_range("frequency", frequency, 0.0, sample_rate / 2, unit="Hz", low_open=True,
                high_open=True)
    k = int(round(frequency * n / sample_rate))
    return 2 * np.fft.rfft(x, axis=-1)[..., k] / n


def phasor_lsq(x, t, frequency: float) -> np.ndarray:
    """Least-squares fit of ``a cos ωt + b sin ωt + c`` at a known frequency.

    Args:
        x: real samples, shape ``(..., n)``.
        t: sample times in s, shape ``(n,)``.
        frequency: Hz.

    Returns:
        ``X = a - j b``, shape ``(...)``.
    """
    x = np.asarray(x, dtype=float)
    wt = 2 * np.pi * frequency * np.asarray(t, dtype=float)
    basis = np.stack([np.cos(wt), np.sin(wt), np.ones_like(wt)], axis=-1)  # (n, 3)
    coef, *_ = np.linalg.lstsq(basis, x.reshape(-1, x.shape[-1]).T, rcond=None)
    return (coef[0] - 1j * coef[1]).reshape(x.shape[:-1])
