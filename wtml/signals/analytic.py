"""Analytic signals ``x + j H{x}`` for time-varying phasors (thesis Eqs. 4.9–4.13).

:func:`analytic_fft` is exact for band-limited periodic records (offline); :func:`analytic_fir`
is causal (real time): a type-III FIR Hilbert transformer of odd length ``numtaps`` and the
real part delayed by the same ``(numtaps - 1)/2`` samples.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import get_window, lfilter


def analytic_fft(x) -> np.ndarray:
    """Analytic signal by FFT along the last axis; shape of ``x``, complex."""
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    h = np.zeros(n)
    h[0] = 1.0
    if n % 2 == 0:
        h[n // 2] = 1.0
        h[1:n // 2] = 2.0
    else:
        h[1:(n + 1) // 2] = 2.0
    return np.fft.ifft(np.fft.fft(x, axis=-1) * h, axis=-1)


def hilbert_fir(numtaps: int, window: str = "blackman") -> np.ndarray:
    """Windowed ideal Hilbert transformer, ``h[n] = 2/(πn)`` for odd ``n``, 0 for even.

    Args:
        numtaps: odd length >= 3; the delay is ``(numtaps - 1)/2`` samples.
        window: a scipy window name.

    Returns:
        taps, shape ``(numtaps,)``.
    """
    if numtaps < 3 or numtaps % 2 == 0:
        raise ValueError(f"numtaps must be odd and >= 3, got {numtaps}")
    n = np.arange(numtaps) - (numtaps - 1) // 2
    h = np.zeros(numtaps)
    odd = n % 2 != 0
    h[odd] = 2 / (np.pi * n[odd])
    return h * get_window(window, numtaps, fftbins=False)


def analytic_fir(x, numtaps: int = 101) -> tuple[np.ndarray, int]:
    """Causal analytic signal along the last axis.

    Returns:
        ``(z, delay)``: ``z[..., k]`` estimates the analytic signal at sample ``k - delay``;
        the first ``numtaps - 1`` samples are the filter's start-up.
    """
    x = np.asarray(x, dtype=float)
    delay = (numtaps - 1) // 2
    real = np.concatenate([np.zeros(x.shape[:-1] + (delay,)), x[..., :x.shape[-1] - delay]],
                          axis=-1)
    return real + 1j * lfilter(hilbert_fir(numtaps), 1.0, x, axis=-1), delay
