"""The one predict interface that decoders and baselines share, so benchmarks treat them alike,
and what a task declares of its outputs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


class FluidPredictor(Protocol):
    """Fluid properties from measured electrical impedances and the device's calibration."""

    name: str

    def predict(self, ze: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        """Args: ze, complex Ω, shape ``(n, n_freq)`` on the predictor's grid; t, the device's
        calibrated T there, complex ``(n, n_freq, 2, 2)``.

        Returns: ``{"eta": (n,) Pa·s, "rho": (n,) kg/m³}``.
        """
        ...


@dataclass(frozen=True)
class OutputRange:
    """What one output of a task may be.

    Attributes:
        low, high: the range the scene trains on, in the output's unit.
        physical: the physically possible range (a negative viscosity, a contact beyond the
            whisker): any method's answer outside it is flagged as impossible.
        margin: how far beyond ``[low, high]`` a decoder's answer still counts as in domain,
            as a fraction of the span (of the log10 span when ``log``).
        log: the range is judged on log10 of the value (positive outputs spanning decades).
        absent_ok: NaN is a legitimate answer, "nothing to locate" (a record without a wall),
            and passes the range check.
    """

    low: float
    high: float
    physical: tuple[float, float]
    margin: float = 0.05
    log: bool = False
    absent_ok: bool = False

    def widened(self) -> tuple[float, float]:
        """``[low, high]`` with the margin, in the output's unit."""
        if self.log:
            lo, hi = np.log10(self.low), np.log10(self.high)
            pad = self.margin * (hi - lo)
            return float(10 ** (lo - pad)), float(10 ** (hi + pad))
        pad = self.margin * (self.high - self.low)
        return self.low - pad, self.high + pad
