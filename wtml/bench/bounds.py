"""Information limits: the Cramér–Rao bound on (η, ρ) for the fluid scene's noise model.

The measurement is Ze on the grid with complex Gaussian noise of relative std ``σ``; the
nuisance is the calibration error (α, β) of ``wtml.scenes.fluid`` with its Gaussian prior.
With θ = (ln η, ln ρ, Re α, Im α, Re β, Im β) the Fisher information is
``J = Gᵀ G + diag(0, 0, 1/s², 1/s², 1/s², 1/s²)``, ``G`` the noise-whitened Jacobian of
(Re Ze, Im Ze) at α = β = 0 (central differences), ``s = calibration_error/√2``; the bound on
the relative error of η is ``sqrt((J⁻¹)₁₁)`` (ρ: ``(J⁻¹)₂₂``). An unbiased estimator that
knows only this model cannot beat it; a decoder can, in part, by learning the scene's prior
over (η, ρ) (glycerol–water ties ρ to η), so it is a reference, not a floor.
"""

from __future__ import annotations

import numpy as np

from wtml.physics import ze_from_zm
from wtml.physics.loads import stokes_sphere
from wtml.scenes.fluid import FluidScene


def fluid_crlb(scene: FluidScene, eta: np.ndarray, rho: np.ndarray, step: float = 1e-6
               ) -> dict[str, np.ndarray]:
    """Relative standard deviations that the bound allows, ``{"eta": (n,), "rho": (n,)}``."""
    t = scene.calibrated_t()
    omega, radius, zref = scene.excitation.omega, scene.sphere.radius, scene.reference_zm()
    theta0 = np.stack([np.log(eta), np.log(rho)] + [np.zeros_like(eta)] * 4, -1)  # (n, 6)

    def ze(theta: np.ndarray) -> np.ndarray:
        zm = stokes_sphere(np.exp(theta[:, :1]), np.exp(theta[:, 1:2]), radius, omega)
        alpha = theta[:, 2:3] + 1j * theta[:, 3:4]
        beta = theta[:, 4:5] + 1j * theta[:, 5:6]
        return ze_from_zm(t, (1 + alpha) * zm + beta * zref)

    z0 = ze(theta0)
    sigma = np.maximum(scene.noise.ze_relative, 1e-12) * np.abs(z0) / np.sqrt(2)
    cols = []
    for k in range(6):
        d = np.zeros(6)
        d[k] = step
        g = (ze(theta0 + d) - ze(theta0 - d)) / (2 * step)
        cols.append(np.concatenate([g.real / sigma, g.imag / sigma], -1))
    jac = np.stack(cols, -1)  # (n, 2 n_freq, 6)
    fisher = np.einsum("nki,nkj->nij", jac, jac)
    s = scene.nuisance.calibration_error / np.sqrt(2)
    prior = np.array([0, 0] + [1 / s**2 if s > 0 else 1e30] * 4)
    cov = np.linalg.inv(fisher + np.diag(prior))
    return {"eta": np.sqrt(cov[:, 0, 0]), "rho": np.sqrt(cov[:, 1, 1])}


def radial_crlb(scene, distance: np.ndarray, stiffness: np.ndarray, step: float = 1e-9
                ) -> np.ndarray:
    """Cramér–Rao bound on the contact distance (m, std) for the radial scene.

    Parameters (d, ln k), the contact stiffness k a nuisance with a Gaussian prior on ln k of
    the std of its log-uniform range (``ln(k_hi/k_lo)/√12``); noise complex Gaussian of
    relative std σ on each Ze, so each frequency adds ``2 Re(∂Ze ∂Ze*)/(σ|Ze|)²`` to the
    Fisher information. Derivatives by central differences of the beam model.
    """
    tr = scene.transducer()
    z0 = scene.ze_of(distance, stiffness, tr)
    grads = []
    for dd, dk in ((step, 0.0), (0.0, 1e-6)):
        plus = scene.ze_of(distance + dd, stiffness * np.exp(dk), tr)
        minus = scene.ze_of(distance - dd, stiffness * np.exp(-dk), tr)
        grads.append((plus - minus) / (2 * (dd or dk)))
    w = 2 / (np.maximum(scene.noise.ze_relative, 1e-12) * np.abs(z0)) ** 2
    fisher = np.empty(distance.shape + (2, 2))
    for i in range(2):
        for j in range(2):
            fisher[:, i, j] = np.sum(w * (grads[i] * np.conj(grads[j])).real, -1)
    lo, hi = scene.contact.stiffness
    fisher[:, 1, 1] += 12 / np.log(hi / lo) ** 2
    return np.sqrt(np.linalg.inv(fisher)[:, 0, 0])
