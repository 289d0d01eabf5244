"""The classical path for fluids, the thesis's closed form: calibrated T -> Zm per
frequency -> (η, ρ) over the band.

Per frequency the sphere law (physics.md §5) is linear in ``u = (η, ρ, q)`` with
``q = sqrt(ηρ)``::

    Re Zm(ω) = 6πR η + 3πR² sqrt(2ω) q
    Im Zm(ω) = (2/3)πR³ω ρ + 3πR² sqrt(2ω) q

so the whole band gives ``2 n_freq`` real equations in three unknowns, solved once by least
squares with unit-norm columns (the pseudo-inverse depends only on the grid and R, so it is
computed once). Noise-free and with a perfect calibration it is exact; a single frequency
reduces to :func:`wtml.physics.loads.fluid_from_zm`.
"""

from __future__ import annotations

import numpy as np

from wtml.physics import zm_from_ze


def band_design(omega: np.ndarray, radius: float) -> np.ndarray:
    """The design matrix, shape ``(2 n_freq, 3)``: rows Re then Im, columns (η, ρ, q)."""
    s = 3 * np.pi * radius**2 * np.sqrt(2 * omega)
    zeros = np.zeros_like(omega)
    re = np.stack([np.full_like(omega, 6 * np.pi * radius), zeros, s], -1)
    im = np.stack([zeros, (2 / 3) * np.pi * radius**3 * omega, s], -1)
    return np.concatenate([re, im])


def band_pseudo_inverse(omega: np.ndarray, radius: float) -> np.ndarray:
    """``pinv(A)`` of :func:`band_design` with column scaling, shape ``(3, 2 n_freq)``."""
    a = band_design(omega, radius)
    scale = np.linalg.norm(a, axis=0)
    return np.linalg.pinv(a / scale) / scale[:, None]


class ClassicalFluid:
    """Baseline predictor (``wtml.interface.FluidPredictor``) in float64 numpy: Ze through the
    user's calibrated T, then the band least squares with the nominal sphere radius.

    Args:
        omega: the grid in rad/s, shape ``(n_freq,)``.
        radius: sphere radius in m.
    """

    name = "thesis closed form numpy"

    def __init__(self, omega: np.ndarray, radius: float) -> None:
        self.omega = np.asarray(omega, dtype=float)
        self.radius = float(radius)
        self.pinv = band_pseudo_inverse(self.omega, self.radius)

    @staticmethod
    def zm(ze: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Fluid load in N·s/m through the calibrated T ``(..., n_freq, 2, 2)``, shape of
        ``ze``."""
        return zm_from_ze(t, ze)

    def predict(self, ze: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        zm = self.zm(np.asarray(ze), t)
        u = np.concatenate([zm.real, zm.imag], axis=-1) @ self.pinv.T
        return {"eta": u[..., 0], "rho": u[..., 1]}
