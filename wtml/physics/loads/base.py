"""The one interface every mechanical load shares."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class Load(ABC):
    """A mechanical load at the whisker tip, seen as its impedance ``Zm = F/V``."""

    @abstractmethod
    def impedance(self, omega: np.ndarray) -> np.ndarray:
        """Load impedance in N·s/m.

        Args:
            omega: angular frequencies in rad/s, any shape ``(...)``, all > 0.

        Returns:
            complex128 array of the shape of ``omega`` (``inf`` for a rigid constraint).
        """
