"""Point impedance of a clamped–free rectangular cantilever touched at a distance from its base.

This is the thesis's calibration load (§4.3): a precision steel strip (82×1×0.3 mm or
82×1×0.2 mm, E = 185 GPa, ρ = 7900 kg/m³) pressed by the whisker tip at ``d`` from its clamped
base, the rest of the strip (``L - d``) overhanging freely.

Two models:

- ``"beam"`` (default, exact for Euler–Bernoulli): the transverse displacement at ``d`` under
  a harmonic point force, from the transfer matrix of the two spans in Krylov–Duncan functions
  (clamped at 0, free at L, shear jump ``F/EI`` at d). Hysteretic loss enters as
  ``EI (1 + j η)``. At 36 Hz the 82×1×0.3 mm strip is just above its first resonance
  (34.9 Hz), which is why the thesis's "theoretical Zm" are small and positive-imaginary
  (mass-like); the quasi-static model cannot reproduce them.
- ``"quasi_static"``: ``k = 3EI/d³`` with the Rayleigh effective mass of the static deflection
  shape, overhang included: ``m = ρA [33 d/140 + ∫_0^{L-d} (1 + 3s/(2d))² ds]``. It is the
  low-frequency limit of the beam model (agreement to O(ω⁴) relative).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wtml.constants import CantileverModel
from wtml.physics.loads.base import Load
from wtml.physics.validation import check_omega, check_range


def krylov_functions(z: np.ndarray) -> np.ndarray:
    """Krylov–Duncan functions ``S, T, U, V`` of ``z = βx``, shape ``z.shape + (4,)``.

    ``S = (cosh z + cos z)/2``, ``T = (sinh z + sin z)/2``, ``U = (cosh z - cos z)/2``,
    ``V = (sinh z - sin z)/2``; their Taylor series are used for ``|z| < 1`` so that the
    small-argument values (``U ≈ z²/2``, ``V ≈ z³/6``) keep full relative precision.
    """
    z = np.asarray(z, dtype=complex)
    out = np.empty(z.shape + (4,), dtype=complex)
    small = np.abs(z) < 1.0
    zs = np.where(small, z, 0.0)
    # series: S = Σ z^{4n}/(4n)!, T = Σ z^{4n+1}/(4n+1)!, U = Σ z^{4n+2}/(4n+2)!, ...
    series = np.zeros(z.shape + (4,), dtype=complex)
    term = np.ones_like(zs)
    for p in range(24):  # |z| < 1: z^24/24! < 1.7e-24, far below rounding
        series[..., p % 4] += term
        term = term * zs / (p + 1)
    zl = np.where(small, 1.0, z)
    ch, sh, c, s = np.cosh(zl), np.sinh(zl), np.cos(zl), np.sin(zl)
    direct = np.stack([(ch + c) / 2, (sh + s) / 2, (ch - c) / 2, (sh - s) / 2], axis=-1)
    out[...] = np.where(small[..., None], series, direct)
    return out


def _transfer(z: np.ndarray) -> np.ndarray:
    """Transfer matrix of an Euler–Bernoulli span for ``y = [w, w'/β, w''/β², w'''/β³]``.

    ``y(x) = K(βx) y(0)``, shape ``z.shape + (4, 4)``.
    """
    s, t, u, v = np.moveaxis(krylov_functions(z), -1, 0)
    return np.stack(
        [
            np.stack([s, t, u, v], -1),
            np.stack([v, s, t, u], -1),
            np.stack([u, v, s, t], -1),
            np.stack([t, u, v, s], -1),
        ],
        axis=-2,
    )


@dataclass(frozen=True)
class CantileverPoint(Load):
    """A rectangular clamped–free strip touched at ``distance`` from its base.

    Attributes:
        length: free length L in m.
        width: width b in m.
        thickness: thickness h in m (bending is across the thickness, ``I = b h³/12``).
        distance: contact distance d from the clamped base in m, ``0 < d <= L``.
        youngs_modulus: E in Pa.
        density: ρ in kg/m³.
        loss_factor: hysteretic loss η (``E -> E (1 + jη)``), beam model only.
        model: ``"beam"`` (exact) or ``"quasi_static"``.
    """

    length: float
    width: float
    thickness: float
    distance: float
    youngs_modulus: float = 185e9
    density: float = 7900.0
    loss_factor: float = 0.0
    model: CantileverModel = "beam"

    def __post_init__(self) -> None:
        for name, unit in (("length", "m"), ("width", "m"), ("thickness", "m"),
                           ("youngs_modulus", "Pa"), ("density", "kg/m³")):
            check_range(name, getattr(self, name), 0.0, np.inf, unit=unit, low_open=True,
                        high_open=True)
        check_range("distance", self.distance, 0.0, self.length, unit="m", low_open=True)
        check_range("loss_factor", self.loss_factor, 0.0, 1.0)
        if self.model not in ("beam", "quasi_static"):
            raise ValueError(f"model must be 'beam' or 'quasi_static', got {self.model!r}")

    @property
    def bending_stiffness(self) -> float:
        """EI in N·m²."""
        return self.youngs_modulus * self.width * self.thickness**3 / 12

    @property
    def mass_per_length(self) -> float:
        """ρA in kg/m."""
        return self.density * self.width * self.thickness

    @property
    def static_stiffness(self) -> float:
        """``3EI/d³`` in N/m."""
        return 3 * self.bending_stiffness / self.distance**3

    @property
    def effective_mass(self) -> float:
        """Rayleigh effective mass of the static deflection shape, overhang included, in kg."""
        d, over = self.distance, self.length - self.distance
        # ∫_0^a (1 + 3s/(2d))² ds = a + 3a²/(2d) + 3a³/(4d²)
        overhang = over + 3 * over**2 / (2 * d) + 3 * over**3 / (4 * d**2)
        return self.mass_per_length * (33 * d / 140 + overhang)

    def impedance(self, omega) -> np.ndarray:
        omega = check_omega(omega)
        if self.model == "quasi_static":
            return 1j * omega * self.effective_mass + self.static_stiffness / (1j * omega)
        ei = self.bending_stiffness * (1 + 1j * self.loss_factor)
        beta = (self.mass_per_length * omega**2 / ei) ** 0.25 + 0j
        k1 = _transfer(beta * self.distance)
        k2 = _transfer(beta * (self.length - self.distance))
        jump = 1.0 / (ei * beta**3)  # unit force: w''' jumps by F/EI, scaled by 1/β³
        # clamped at 0: y(0) = [0, 0, c, d]; free at L: rows 2, 3 of y(L) vanish
        m = k2[..., 2:4, :] @ k1[..., :, 2:4]
        rhs = -jump[..., None] * k2[..., 2:4, 3]
        det = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]
        # Cramer's rule, w(d) = w_num / det; Zm = F/(jω w) = det/(jω w_num) is exactly 0 at
        # a natural frequency of the strip (det = 0) instead of a division by zero
        c_num = rhs[..., 0] * m[..., 1, 1] - m[..., 0, 1] * rhs[..., 1]
        d_num = m[..., 0, 0] * rhs[..., 1] - m[..., 1, 0] * rhs[..., 0]
        w_num = k1[..., 0, 2] * c_num + k1[..., 0, 3] * d_num
        return det / (1j * omega * w_num)
