"""Argument checks that name the offending field and its allowed range."""

from __future__ import annotations

import numpy as np


def check_range(name: str, value, low: float, high: float, *, unit: str = "",
                low_open: bool = False, high_open: bool = False) -> np.ndarray:
    """Return ``value`` as a float array after checking ``low <= value <= high`` elementwise.

    Raises:
        ValueError: naming ``name``, the allowed range and the worst offending value, for any
            value out of range or not finite.
    """
    arr = np.asarray(value, dtype=float)
    lo_ok = arr > low if low_open else arr >= low
    hi_ok = arr < high if high_open else arr <= high
    bad = ~(lo_ok & hi_ok)  # NaN fails both comparisons
    if np.any(bad):
        worst = arr[bad].flat[0]
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        unit_txt = f" {unit}" if unit else ""
        raise ValueError(
            f"{name} must be in {left}{low:g}, {high:g}{right}{unit_txt}; got {float(worst):g}"
            + (f" ({int(bad.sum())} values out of range)" if bad.sum() > 1 else "")
        )
    return arr


def check_omega(omega) -> np.ndarray:
    """Angular frequencies: finite and > 0 rad/s."""
    return check_range("omega", omega, 0.0, np.inf, unit="rad/s", low_open=True,
                       high_open=True)
