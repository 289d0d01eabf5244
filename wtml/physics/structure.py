"""The one interface every transducer structure shares."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class Structure(ABC):
    """A piezo-coupled structure seen through its electrical and tip ports."""

    @abstractmethod
    def transduction_matrix(self, omega: np.ndarray) -> np.ndarray:
        """T(ω) of the structure with a free tip.

        Args:
            omega: angular frequencies in rad/s, shape ``(n_freq,)`` (or any shape ``(...)``).

        Returns:
            complex128 array of shape ``omega.shape + (2, 2)`` with det T = 1.
        """
