"""Radial-location baselines, with the decoders' predict interface (``{"distance": m}``).

- :class:`PolynomialRadial`: the thesis's 9th-degree polynomials of d in Re Ze or in Im Ze
  at the first frequency (scikit-learn: standardise, polynomial features, least squares).
- :class:`InversionRadial`: the physics inversion. The forward model (the scene's beam model)
  is tabulated once on a fine grid of d and a log grid of the contact stiffness (the
  nuisance is estimated jointly); each measurement takes the grid point of least relative
  misfit over the frequencies and refines d by a parabola through its neighbours at that
  stiffness (a 1-D root-finding of the misfit's derivative, vectorised).
"""

from __future__ import annotations

import numpy as np
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import PolynomialFeatures, StandardScaler


class PolynomialRadial:
    """d as a polynomial of one part of Ze at the first frequency.

    Args:
        part: ``"real"`` or ``"imag"``.
        degree: polynomial degree (the thesis: 9).
    """

    def __init__(self, part: str, degree: int = 9) -> None:
        if part not in ("real", "imag"):
            raise ValueError(f"part must be 'real' or 'imag', got {part!r}")
        self.part, self.name = part, f"polynomial {degree} in {'Re' if part == 'real' else 'Im'} Ze"
        self.model = make_pipeline(StandardScaler(), PolynomialFeatures(degree),
                                   LinearRegression())

    def _x(self, ze: np.ndarray) -> np.ndarray:
        z = np.asarray(ze)[:, 0]
        return (z.real if self.part == "real" else z.imag)[:, None]

    def fit(self, ze: np.ndarray, distance: np.ndarray) -> PolynomialRadial:
        self.model.fit(self._x(ze), distance)
        return self

    def predict(self, ze: np.ndarray) -> dict[str, np.ndarray]:
        return {"distance": self.model.predict(self._x(ze))}


class InversionRadial:
    """Physics inversion on the forward model (module docstring).

    Args:
        scene: a ``RadialScene``.
        step: grid spacing in m (default 1 µm).
    """

    name = "physics inversion"

    def __init__(self, scene, step: float = 1e-6, n_stiffness: int = 17) -> None:
        lo, hi = 1e-6 * np.array(scene.contact.distance_um)
        if scene.contact.distances_um:
            lo, hi = 0.0, 1e-6 * max(scene.contact.distances_um) * 1.2
        self.grid = np.arange(lo, hi + step / 2, step)
        ks = np.geomspace(*scene.contact.stiffness, n_stiffness)
        tr = scene.transducer()
        d, k = np.meshgrid(self.grid, ks, indexing="ij")
        self.table = scene.ze_of(d.ravel(), k.ravel(), tr).reshape(
            len(self.grid), n_stiffness, -1)  # (n_grid, n_k, n_freq)
        self.step = step

    def predict(self, ze: np.ndarray, chunk: int = 256) -> dict[str, np.ndarray]:
        ze = np.asarray(ze)
        out = np.empty(len(ze))
        for s in range(0, len(ze), chunk):
            z = ze[s:s + chunk, None, None, :]
            m = np.sum(np.abs((z - self.table[None]) / self.table[None]) ** 2, -1)
            best_k = np.argmin(m.min(1), -1)  # (n,)
            rows = np.arange(len(best_k))
            mk = m[rows, :, best_k]  # misfit along d at the best stiffness, (n, n_grid)
            i = np.clip(np.argmin(mk, -1), 1, len(self.grid) - 2)
            f0, f1, f2 = mk[rows, i - 1], mk[rows, i], mk[rows, i + 1]
            curv = f0 - 2 * f1 + f2
            shift = np.where(curv > 0, 0.5 * (f0 - f2) / np.where(curv > 0, curv, 1), 0.0)
            out[s:s + chunk] = self.grid[i] + np.clip(shift, -1, 1) * self.step
        return {"distance": out}
