"""Sphere oscillating in a Newtonian fluid (Eqs. 6.1–6.2, 6.13) and its closed-form inverse
(Eqs. 6.16–6.17).

With penetration depth ``δ = sqrt(2η/(ωρ))``::

    cf = 6πηR + 3πR² sqrt(2ηρω)            (damping, N·s/m)
    mf = (2/3)πR³ρ + 3πR² sqrt(2ηρ/ω)      (added mass, kg)
    Zm = cf + jω mf
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from wtml.physics.loads.base import Load
from wtml.physics.validation import check_omega, check_range


def stokes_sphere(eta, rho, radius, omega) -> np.ndarray:
    """Impedance of a sphere oscillating in a Newtonian fluid, in N·s/m.

    Args:
        eta: dynamic viscosity in Pa·s, > 0.
        rho: density in kg/m³, > 0.
        radius: sphere radius in m, > 0.
        omega: angular frequency in rad/s, > 0.

    All four broadcast together; the result has the broadcast shape.
    """
    eta = check_range("eta", eta, 0.0, np.inf, unit="Pa·s", low_open=True, high_open=True)
    rho = check_range("rho", rho, 0.0, np.inf, unit="kg/m³", low_open=True, high_open=True)
    radius = check_range("radius", radius, 0.0, np.inf, unit="m", low_open=True,
                         high_open=True)
    omega = check_omega(omega)
    s = 3 * np.pi * radius**2 * np.sqrt(2 * eta * rho * omega)  # boundary-layer term
    return (6 * np.pi * eta * radius + s) + 1j * ((2 / 3) * np.pi * radius**3 * rho * omega + s)


def fluid_from_zm(zm, radius, omega, *, on_invalid: Literal["raise", "nan"] = "raise"
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Viscosity and density from the impedance of a sphere in a fluid (the analytic baseline).

    With ``X = Re Zm = aη + s``, ``Y = Im Zm = Bρ + s``, ``a = 6πR``, ``B = (2/3)πR³ω``,
    ``s = 3πR² sqrt(2ωηρ)``: eliminating ρ through ``s² = 18π²R⁴ω ηρ`` leaves
    ``126π²R² η² + πR(27Y - 15X) η - X² = 0``, whose roots have product ``-X²/(126π²R²) < 0``:
    exactly one is positive. It is taken in the cancellation-free form
    ``η = 2X² / (b + sqrt(b² + 4AX²))`` when ``b >= 0`` and ``(-b + sqrt(b² + 4AX²)) / 2A``
    otherwise. Then ``s = X - aη`` and ``ρ = s² / (18π²R⁴ω η)``.

    Args:
        zm: load impedance in N·s/m, shape ``(...)``.
        radius: sphere radius in m, broadcastable.
        omega: angular frequency in rad/s, broadcastable.
        on_invalid: ``"raise"`` (default) raises for any Zm that no Newtonian fluid produces
            (``Re Zm <= 0``, a boundary-layer term ``s < 0``, or ``Im Zm <= s``, which
            would need a density <= 0); ``"nan"`` returns NaN there instead (for noisy batches).

    Returns:
        ``(eta, rho)`` in Pa·s and kg/m³, the broadcast shape.

    Raises:
        ValueError: naming the condition violated and how many inputs violate it.
    """
    if on_invalid not in ("raise", "nan"):
        raise ValueError(f"on_invalid must be 'raise' or 'nan', got {on_invalid!r}")
    zm = np.asarray(zm, dtype=complex)
    radius = check_range("radius", radius, 0.0, np.inf, unit="m", low_open=True,
                         high_open=True)
    omega = check_omega(omega)
    x, y = zm.real, zm.imag
    quad_a = 126 * np.pi**2 * radius**2
    quad_b = np.pi * radius * (27 * y - 15 * x)
    root = np.sqrt(quad_b**2 + 4 * quad_a * x**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = np.where(quad_b >= 0, 2 * x**2 / (quad_b + root), (root - quad_b) / (2 * quad_a))
        s = x - 6 * np.pi * radius * eta
        rho = s**2 / (18 * np.pi**2 * radius**4 * omega * eta)
    # s >= 0 and Bρ = Y - s > 0, each within the rounding of the difference that makes it
    tol = 8 * np.finfo(float).eps
    invalid = (~np.isfinite(zm) | (x <= 0) | (s < -tol * np.abs(x))
               | (y - s <= -tol * np.abs(y)))
    if np.any(invalid):
        if on_invalid == "raise":
            n = int(np.count_nonzero(invalid))
            first = np.flatnonzero(invalid.ravel())[0] if invalid.ndim else 0
            raise ValueError(
                f"zm cannot be the load of a sphere in a Newtonian fluid at {n} of "
                f"{invalid.size} points (first at flat index {first}: "
                f"zm={np.broadcast_to(zm, invalid.shape).ravel()[first]!r}); a fluid load "
                "needs Re Zm > 0, a boundary-layer term s = Re Zm - 6πRη >= 0 and a positive "
                "density, Im Zm - s > 0"
            )
        eta = np.where(invalid, np.nan, eta)
        rho = np.where(invalid, np.nan, rho)
    return eta, rho


@dataclass(frozen=True)
class SphereInFluid(Load):
    """A rigid sphere of ``radius`` (m) in a fluid of viscosity ``eta`` (Pa·s) and density
    ``rho`` (kg/m³). Its own mass is not included: carry it as :func:`tip_mass`."""

    radius: float
    eta: float
    rho: float

    def __post_init__(self) -> None:
        stokes_sphere(self.eta, self.rho, self.radius, 1.0)  # validates all three

    def impedance(self, omega) -> np.ndarray:
        return stokes_sphere(self.eta, self.rho, self.radius, omega)
