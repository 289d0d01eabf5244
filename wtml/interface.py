"""The one predict interface that decoders and baselines share, so benchmarks treat them alike."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class FluidPredictor(Protocol):
    """Fluid properties from measured electrical impedances."""

    name: str

    def predict(self, ze: np.ndarray) -> dict[str, np.ndarray]:
        """Args: ze, complex Ω, shape ``(n, n_freq)`` on the predictor's grid.

        Returns: ``{"eta": (n,) Pa·s, "rho": (n,) kg/m³}``.
        """
        ...
