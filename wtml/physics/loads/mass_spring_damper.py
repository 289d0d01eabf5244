"""Mass–spring–damper load (Eq. 3.48)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wtml.physics.loads.base import Load
from wtml.physics.validation import check_omega, check_range


@dataclass(frozen=True)
class MassSpringDamper(Load):
    """``Zm = c + jωm + k/(jω)``.

    Attributes:
        m: mass in kg (>= 0).
        k: stiffness in N/m (>= 0).
        c: damping in N·s/m (>= 0).
    """

    m: float = 0.0
    k: float = 0.0
    c: float = 0.0

    def __post_init__(self) -> None:
        for name, unit in (("m", "kg"), ("k", "N/m"), ("c", "N·s/m")):
            check_range(name, getattr(self, name), 0.0, np.inf, unit=unit, high_open=True)

    def impedance(self, omega) -> np.ndarray:
        omega = check_omega(omega)
        return self.c + 1j * omega * self.m + self.k / (1j * omega)
