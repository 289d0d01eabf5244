"""Excitation waveforms and sampling. Times in s, frequencies in Hz, amplitudes in V."""

from __future__ import annotations

import numpy as np
from scipy.signal import chirp

from wtml.physics.validation import check_range


def sample_times(duration: float, sample_rate: float) -> np.ndarray:
    """``n = round(duration · sample_rate)`` sample instants from 0, shape ``(n,)``."""
    check_range("duration", duration, 0.0, np.inf, unit="s", low_open=True, high_open=True)
    check_range("sample_rate", sample_rate, 0.0, np.inf, unit="Hz", low_open=True,
                high_open=True)
    return np.arange(int(round(duration * sample_rate))) / sample_rate


def tone(t, frequency: float, amplitude: float = 1.0, phase: float = 0.0) -> np.ndarray:
    """``A cos(2π f t + φ)``, the real part of the phasor ``A e^{jφ}``; shape of ``t``."""
    check_range("frequency", frequency, 0.0, np.inf, unit="Hz", high_open=True)
    return amplitude * np.cos(2 * np.pi * frequency * np.asarray(t) + phase)


def multitone(t, frequencies, amplitudes, phases=None) -> np.ndarray:
    """Sum of tones, e.g. the whisking + touch excitation ``AL cos ωL t + AH cos ωH t``.

    Args:
        t: times, shape ``(n,)``.
        frequencies, amplitudes, phases: shape ``(k,)`` each (phases default 0).

    Returns:
        shape ``(n,)``.
    """
    f = np.atleast_1d(np.asarray(frequencies, dtype=float))
    a = np.broadcast_to(np.asarray(amplitudes, dtype=float), f.shape)
    p = np.zeros_like(f) if phases is None else np.broadcast_to(np.asarray(phases, float), f.shape)
    check_range("frequencies", f, 0.0, np.inf, unit="Hz", high_open=True)
    return np.sum(a * np.cos(2 * np.pi * f * np.asarray(t)[:, None] + p), axis=-1)


def sweep(t, f_start: float, f_stop: float, amplitude: float = 1.0,
          method: str = "linear") -> np.ndarray:
    """A swept sine from ``f_start`` to ``f_stop`` over the span of ``t`` (scipy ``chirp``).

    Args:
        t: times, shape ``(n,)``, n >= 2.
        f_start, f_stop: Hz, > 0.
        amplitude: V.
        method: ``"linear"`` or ``"logarithmic"``.
    """
    t = np.asarray(t, dtype=float)
    check_range("f_start", f_start, 0.0, np.inf, unit="Hz", low_open=True, high_open=True)
    check_range("f_stop", f_stop, 0.0, np.inf, unit="Hz", low_open=True, high_open=True)
    if method not in ("linear", "logarithmic"):
        raise ValueError(f"method must be 'linear' or 'logarithmic', got {method!r}")
    if t.size < 2:
        raise ValueError("sweep needs at least 2 samples")
    return amplitude * chirp(t - t[0], f_start, t[-1] - t[0], f_stop, method=method)


def lead_in(t, e, de, lead_s: float) -> tuple[np.ndarray, np.ndarray]:
    """A drive started from rest: ``e`` (V) and its rate ``de`` (V/s) at instants ``t`` (s,
    the lead-in from ``-lead_s`` to 0), times a raised-cosine ramp from 0 at ``-lead_s`` to 1
    at 0 (the rate by the product rule). Shapes broadcast; returns ``(e, de)`` ramped."""
    check_range("lead_s", lead_s, 0.0, np.inf, low_open=True, high_open=True)
    x = np.clip((np.asarray(t, float) + lead_s) / lead_s, 0.0, 1.0)
    ramp, dramp = 0.5 - 0.5 * np.cos(np.pi * x), 0.5 * np.pi / lead_s * np.sin(np.pi * x)
    return e * ramp, de * ramp + e * dramp
