"""Whisker-shaft contact stiffness (Eqs. 3.49–3.51)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wtml.physics.loads.base import Load
from wtml.physics.validation import check_omega, check_range


@dataclass(frozen=True)
class WhiskerContact(Load):
    """A round whisker of length L pinned by an object at ``distance_from_tip`` d.

    The tip sees the stiffness of the free span beyond the contact,
    ``k = 3EI/(L - d)³`` with ``I = π r⁴/4``, and ``Zm = k/(jω)``. Nonlinear in d: the inverse
    problem d <- Ze is the radial-location task. (The beam model of the whole transducer is
    exact for a contact on the shaft; this quasi-static spring is the thesis's simple view.)

    Attributes:
        length: whisker length L in m.
        radius: whisker radius r in m.
        distance_from_tip: contact distance d from the tip in m, ``0 <= d < L``.
        youngs_modulus: E in Pa (steel 185 GPa).
    """

    length: float
    radius: float
    distance_from_tip: float
    youngs_modulus: float = 185e9

    def __post_init__(self) -> None:
        for name, unit in (("length", "m"), ("radius", "m"), ("youngs_modulus", "Pa")):
            check_range(name, getattr(self, name), 0.0, np.inf, unit=unit, low_open=True,
                        high_open=True)
        check_range("distance_from_tip", self.distance_from_tip, 0.0, self.length, unit="m",
                    high_open=True)

    @property
    def stiffness(self) -> float:
        """``3EI/(L-d)³`` in N/m."""
        second_moment = np.pi * self.radius**4 / 4
        return 3 * self.youngs_modulus * second_moment / (self.length - self.distance_from_tip) ** 3

    def impedance(self, omega) -> np.ndarray:
        omega = check_omega(omega)
        return self.stiffness / (1j * omega)
