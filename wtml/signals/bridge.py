"""The auto-balancing bridge (thesis Eqs. 4.1–4.3).

The device current flows into a virtual ground through a feedback (range) resistor ``Rr``;
the current channel reads ``Vr = Rr I`` (sign normalised by the instrument), the voltage
channel ``Vx = E``, and ``Zx = Rr Vx / Vr``.
"""

from __future__ import annotations

import numpy as np

from wtml.physics.validation import check_range


def bridge_channels(e, i, range_resistor: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Vx, Vr)`` in V that the bridge reads for a device voltage ``e`` (V) and current
    ``i`` (A); phasors or samples, any broadcastable shapes."""
    check_range("range_resistor", range_resistor, 0.0, np.inf, unit="Ω", low_open=True,
                high_open=True)
    return np.asarray(e), range_resistor * np.asarray(i)


def impedance_from_bridge(vx, vr, range_resistor: float) -> np.ndarray:
    """``Zx = Rr Vx / Vr`` in Ω from the two channels' phasors (any broadcastable shapes)."""
    check_range("range_resistor", range_resistor, 0.0, np.inf, unit="Ω", low_open=True,
                high_open=True)
    vr = np.asarray(vr)
    if np.any(vr == 0):
        raise ValueError("vr has a zero phasor: no current was measured")
    return range_resistor * np.asarray(vx) / vr
