"""The best achievable fluid estimate: the exact Bayes posterior mean under the scene's own
prior, noise and calibration error (the fluid task's "best achievable" reference).

The scene (``wtml.scenes.fluid``) draws a glycerol–water specimen uniformly in volume
fraction and temperature, and the calibrated T reports ``z = (1 + α) Zm(θ) + β Zref`` with α, β
circular complex Gaussian (``E|α|² = E|β|² = c²``, c the calibration error), seen through
noise of relative std σ on Ze. Mapped back through the calibrated T, the measurement is
``z = zm_from_ze(T, Ze)``, and the Ze noise becomes circular Gaussian noise on z of variance
``d_k = σ² |Ze_k|² |det T|² / |t11 - t21 Ze_k|⁴`` per frequency (its first-order map; the
second order is σ² ~ 1e-8 relative). Given θ = (volume fraction, temperature), z is then
linear-Gaussian in (α, β), so they integrate out exactly:

    z ~ CN(Zm(θ), D + c² B Bᴴ),   B = [Zm(θ), Zref 1]   (n_freq × 2),

whose log-likelihood needs one 2×2 Hermitian system per (measurement, θ) (Woodbury). The
posterior over a grid of θ (uniform prior, the scene's ranges) gives the posterior means of η
and ρ. Cost: ``n_grid`` × n_freq complex multiply-adds per measurement, about 1 ms each on
2 cores at the default grid; this is a reference, not a device method.
"""

from __future__ import annotations

import numpy as np

from wtml.physics import zm_from_ze
from wtml.physics.fluids import glycerol_water
from wtml.physics.loads import stokes_sphere


class BayesFluid:
    """Posterior means of η and ρ (``wtml.interface.FluidPredictor``).

    Args:
        scene: a ``FluidScene``.
        n_fraction, n_temperature: grid points over the scene's ranges (uniform prior).
        chunk: measurements per vectorised block (memory ~ chunk × grid × 80 bytes).
    """

    name = "Bayes posterior mean"

    def __init__(self, scene, n_fraction: int = 400, n_temperature: int = 100,
                 chunk: int = 64) -> None:
        cv, temp = np.meshgrid(np.linspace(*scene.fluid.volume_fraction, n_fraction),
                               np.linspace(*scene.fluid.temperature_c, n_temperature))
        self.eta, self.rho = glycerol_water(cv.ravel(), temp.ravel())  # (n_grid,)
        omega = scene.excitation.omega
        self.zm = stokes_sphere(self.eta[:, None], self.rho[:, None], scene.sphere.radius,
                                omega)  # (n_grid, n_freq)
        self.zm_t = np.ascontiguousarray(self.zm.T)
        self.zm2_t = np.ascontiguousarray((np.abs(self.zm) ** 2).T)
        self.t = scene.calibrated_t()
        self.zref = scene.reference_zm()
        self.sigma = max(scene.noise.ze_relative, 1e-12)
        self.inv_p = 1.0 / max(scene.nuisance.calibration_error, 1e-12) ** 2
        self.chunk = chunk

    def _noise_weights(self, ze: np.ndarray) -> np.ndarray:
        """``1 / d_k`` (module docstring), shape of ``ze``."""
        t11, t12, t21, t22 = (self.t[:, i, j] for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)))
        det = np.abs(t11 * t22 - t12 * t21)
        return np.abs(t11 - t21 * ze) ** 4 / (self.sigma * np.abs(ze) * det) ** 2

    def log_likelihood(self, ze: np.ndarray) -> np.ndarray:
        """``log p(Ze | θ)`` up to a constant per measurement, shape ``(n, n_grid)``."""
        z, w = zm_from_ze(self.t, ze), self._noise_weights(ze)
        s_zz = np.sum(w * np.abs(z) ** 2, -1)[:, None]
        s_z = np.sum(w * z, -1)[:, None]
        s_1 = np.sum(w, -1)[:, None]
        s_zm = (w * np.conj(z)) @ self.zm_t  # Σ w z̄ Zm
        s_mm = w @ self.zm2_t  # Σ w |Zm|²
        s_m = w @ self.zm_t  # Σ w Zm
        q1 = s_zz - 2 * s_zm.real + s_mm
        b1, b2 = np.conj(s_zm) - s_mm, self.zref * (s_z - s_m)
        m11, m22, m12 = self.inv_p + s_mm, self.inv_p + self.zref**2 * s_1, self.zref * np.conj(s_m)
        det = m11 * m22 - np.abs(m12) ** 2
        quad = (m22 * np.abs(b1) ** 2 - 2 * (np.conj(b1) * m12 * b2).real
                + m11 * np.abs(b2) ** 2) / det
        return -(q1 - quad) - np.log(det)

    def predict(self, ze: np.ndarray) -> dict[str, np.ndarray]:
        ze = np.atleast_2d(np.asarray(ze, dtype=complex))
        eta, rho = np.empty(len(ze)), np.empty(len(ze))
        for s in range(0, len(ze), self.chunk):
            logl = self.log_likelihood(ze[s:s + self.chunk])
            post = np.exp(logl - logl.max(-1, keepdims=True))
            post /= post.sum(-1, keepdims=True)
            eta[s:s + self.chunk], rho[s:s + self.chunk] = post @ self.eta, post @ self.rho
        return {"eta": eta, "rho": rho}
