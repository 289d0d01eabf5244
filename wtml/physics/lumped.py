"""Lumped single-mode transducer model (physics.md §3, last paragraph).

Governing equations, with tip force ``F`` on the load and tip velocity ``V``::

    φ E = Zt V + F,        I = jω C0 E + φ V,        Zt = c + jω m + k/(jω)

give ``T = [[1/φ, Zt/φ], [jω C0/φ, jω C0 Zt/φ + φ]]`` with det T = 1 identically.
Dielectric loss enters as a complex clamped capacitance ``C0 (1 - j tanδ)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wtml.physics.structure import Structure
from wtml.physics.validation import check_omega, check_range


@dataclass(frozen=True)
class LumpedTransducer(Structure):
    """One mechanical mode coupled to a capacitor.

    Attributes:
        c0: clamped (blocked) capacitance, in F.
        phi: electromechanical coupling factor, in N/V (= A·s/m).
        k: modal stiffness referred to the tip, in N/m.
        m: modal mass referred to the tip, in kg.
        c: modal damping referred to the tip, in N·s/m.
        tan_delta: dielectric loss tangent (dimensionless), ``C0 -> C0 (1 - j tanδ)``.
    """

    c0: float
    phi: float
    k: float
    m: float
    c: float
    tan_delta: float = 0.0

    def __post_init__(self) -> None:
        check_range("c0", self.c0, 0.0, np.inf, unit="F", low_open=True, high_open=True)
        check_range("phi", self.phi, 0.0, np.inf, unit="N/V", low_open=True, high_open=True)
        check_range("k", self.k, 0.0, np.inf, unit="N/m", high_open=True)
        check_range("m", self.m, 0.0, np.inf, unit="kg", low_open=True, high_open=True)
        check_range("c", self.c, 0.0, np.inf, unit="N·s/m", high_open=True)
        check_range("tan_delta", self.tan_delta, 0.0, 1.0)

    @classmethod
    def from_resonance(cls, *, c0: float, phi: float, m: float, f0: float, q: float,
                       tan_delta: float = 0.0) -> LumpedTransducer:
        """Build from a free-tip mechanical resonance ``f0`` (Hz) and quality factor ``q``:
        ``k = m (2π f0)^2``, ``c = m 2π f0 / q``."""
        check_range("f0", f0, 0.0, np.inf, unit="Hz", low_open=True, high_open=True)
        check_range("q", q, 0.0, np.inf, low_open=True, high_open=True)
        w0 = 2 * np.pi * f0
        return cls(c0=c0, phi=phi, k=m * w0**2, m=m, c=m * w0 / q, tan_delta=tan_delta)

    def mechanical_impedance(self, omega) -> np.ndarray:
        """``Zt = c + jωm + k/(jω)`` in N·s/m, shape of ``omega``."""
        omega = check_omega(omega)
        return self.c + 1j * omega * self.m + self.k / (1j * omega)

    def capacitance(self) -> complex:
        """Complex clamped capacitance ``C0 (1 - j tanδ)`` in F."""
        return self.c0 * (1 - 1j * self.tan_delta)

    def transduction_matrix(self, omega) -> np.ndarray:
        """T(ω), shape ``omega.shape + (2, 2)``, complex128, det T = 1 to rounding."""
        omega = check_omega(omega)
        zt = self.mechanical_impedance(omega)
        jwc = 1j * omega * self.capacitance()
        phi = self.phi
        t = np.empty(omega.shape + (2, 2), dtype=complex)
        t[..., 0, 0] = 1 / phi
        t[..., 0, 1] = zt / phi
        t[..., 1, 0] = jwc / phi
        t[..., 1, 1] = jwc * zt / phi + phi
        return t
