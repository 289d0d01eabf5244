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
and ρ. Each measurement comes with its device's calibrated T (the scene's ``t``); the sphere's
radius, which the device spread draws uniformly in ``R0 (1 ± s)`` and nobody measures, is
integrated out by Gauss–Legendre quadrature over that interval (``n_radius`` nodes).
Cost: ``n_grid`` × n_freq complex multiply-adds per measurement (× ``n_radius`` with a radius
spread), about 1 ms each on
2 cores at the default grid; this is a reference, not a device method.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from wtml.physics import zm_from_ze
from wtml.physics.fluids import glycerol_water
from wtml.physics.loads import stokes_sphere


class BayesFluid:
    """Posterior means of η and ρ (``wtml.interface.FluidPredictor``).

    Args:
        scene: a ``FluidScene``.
        n_fraction, n_temperature: grid points over the scene's ranges (uniform prior).
        n_radius: quadrature nodes over the sphere's radius (one, the nominal, without its
            spread).
        chunk: measurements per vectorised block (memory ~ chunk × grid × 80 bytes).
    """

    name = "Bayes posterior mean"

    def __init__(self, scene, n_fraction: int = 400, n_temperature: int = 100,
                 n_radius: int = 5, chunk: int = 64) -> None:
        cv, temp = np.meshgrid(np.linspace(*scene.fluid.volume_fraction, n_fraction),
                               np.linspace(*scene.fluid.temperature_c, n_temperature))
        self.eta, self.rho = glycerol_water(cv.ravel(), temp.ravel())  # (n_grid,)
        omega = scene.excitation.omega
        spread = scene.spread.sphere_radius
        nodes, weights = (np.polynomial.legendre.leggauss(n_radius) if spread > 0
                          else (np.zeros(1), np.full(1, 2.0)))
        self.log_w = np.log(weights / 2)  # the uniform prior's quadrature weights
        self.zm_t, self.zm2_t = [], []
        for u in nodes:
            zm = stokes_sphere(self.eta[:, None], self.rho[:, None],
                               scene.sphere.radius * (1 + spread * u), omega)  # (n_grid, n_freq)
            self.zm_t.append(np.ascontiguousarray(zm.T))
            self.zm2_t.append(np.ascontiguousarray((np.abs(zm) ** 2).T))
        self.zref = scene.reference_zm()
        self.sigma = max(scene.noise.ze_relative, 1e-12)
        self.inv_p = 1.0 / max(scene.nuisance.calibration_error, 1e-12) ** 2
        self.chunk = chunk

    def _noise_weights(self, ze: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``1 / d_k`` (module docstring), shape of ``ze``."""
        t11, t12, t21, t22 = (t[..., i, j] for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)))
        det = np.abs(t11 * t22 - t12 * t21)
        return np.abs(t11 - t21 * ze) ** 4 / (self.sigma * np.abs(ze) * det) ** 2

    def log_likelihood(self, ze: np.ndarray, t: np.ndarray, node: int = 0) -> np.ndarray:
        """``log p(Ze | θ, R)`` up to a constant per measurement, shape ``(n, n_grid)``, at the
        radius quadrature node ``node``; ``t`` each measurement's calibrated T."""
        z, w = zm_from_ze(t, ze), self._noise_weights(ze, t)
        s_zz = np.sum(w * np.abs(z) ** 2, -1)[:, None]
        s_z = np.sum(w * z, -1)[:, None]
        s_1 = np.sum(w, -1)[:, None]
        s_zm = (w * np.conj(z)) @ self.zm_t[node]  # Σ w z̄ Zm
        s_mm = w @ self.zm2_t[node]  # Σ w |Zm|²
        s_m = w @ self.zm_t[node]  # Σ w Zm
        q1 = s_zz - 2 * s_zm.real + s_mm
        b1, b2 = np.conj(s_zm) - s_mm, self.zref * (s_z - s_m)
        m11, m22, m12 = self.inv_p + s_mm, self.inv_p + self.zref**2 * s_1, self.zref * np.conj(s_m)
        det = m11 * m22 - np.abs(m12) ** 2
        quad = (m22 * np.abs(b1) ** 2 - 2 * (np.conj(b1) * m12 * b2).real
                + m11 * np.abs(b2) ** 2) / det
        return -(q1 - quad) - np.log(det)

    def posteriors(self, ze: np.ndarray, t: np.ndarray) -> Iterator[tuple[slice, np.ndarray]]:
        """The posterior over the grid (the radius integrated out) of :attr:`chunk`
        measurements at a time: ``(rows, weights (len(rows), n_grid))``, each row summing to
        1; ``ze`` complex ``(n, n_freq)`` Ω, ``t`` each one's calibrated T."""
        ze = np.atleast_2d(np.asarray(ze, dtype=complex))
        t = np.broadcast_to(t, (*ze.shape, 2, 2))
        for s in range(0, len(ze), self.chunk):
            rows = slice(s, min(s + self.chunk, len(ze)))
            logl = np.stack([self.log_likelihood(ze[rows], t[rows], k) + self.log_w[k]
                             for k in range(len(self.log_w))])
            post = np.exp(logl - logl.max((0, -1), keepdims=True)).sum(0)
            yield rows, post / post.sum(-1, keepdims=True)

    def predict(self, ze: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        n = len(np.atleast_2d(ze))
        eta, rho = np.empty(n), np.empty(n)
        for rows, post in self.posteriors(ze, t):
            eta[rows], rho[rows] = post @ self.eta, post @ self.rho
        return {"eta": eta, "rho": rho}

    def intervals(self, ze: np.ndarray, t: np.ndarray, levels: tuple[float, ...]
                  ) -> dict[str, dict[str, np.ndarray]]:
        """The posterior's own uncertainty of ln η and ρ, as a decoder's σ is read
        (``wtml bench coverage``): per value (``"eta"``: of ln η; ``"rho"``) its posterior
        ``mean`` and ``std`` ``(n,)`` and its central credible intervals ``(n, len(levels),
        2)`` at ``levels`` (shares of the posterior, e.g. 0.6827 and 0.95)."""
        n = len(np.atleast_2d(ze))
        values = {"eta": np.log(self.eta), "rho": self.rho}
        out = {k: {"mean": np.empty(n), "std": np.empty(n),
                   "central": np.empty((n, len(levels), 2))} for k in values}
        tails = np.array([[(1 - q) / 2, (1 + q) / 2] for q in levels])
        orders = {name: np.argsort(grid) for name, grid in values.items()}
        for rows, post in self.posteriors(ze, t):
            for name, grid in values.items():
                mean = post @ grid
                out[name]["mean"][rows] = mean
                out[name]["std"][rows] = np.sqrt(np.maximum(post @ grid**2 - mean**2, 0.0))
                order = orders[name]
                cdf = np.cumsum(post[:, order], -1)
                at = np.stack([(cdf < q).sum(-1) for q in tails.ravel()], -1)
                out[name]["central"][rows] = grid[order][np.minimum(at, len(grid) - 1)].reshape(
                    -1, *tails.shape)
        return out
