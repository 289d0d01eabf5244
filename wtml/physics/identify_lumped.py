"""Identification of a one-mode lumped transducer and its tip sphere from free sweeps.

The lumped counterpart of :mod:`wtml.physics.identify` (whose fit is the beam's), for the
fluid task's device (physics.md §3, ``wtml.physics.lumped``): Ze(ω) with the tip free or under
a tip load of known Zm (a calibration load), with or without the sphere mounted, fitted by
least squares on ``log(Ze_model / Ze_measured)`` (real and imaginary parts, each in units of
its stated uncertainty ``σ/√2``) over factors of the parameters ``c0, phi, k, m, c,
tan_delta`` and ``sphere_radius`` (the sphere's mass ``ρ 4/3 π R³`` at its known density
rides on the tip). Standard errors come from the Jacobian at the solution, scaled by the
reduced χ² where that is above 1.

What each measurement shows: a free sweep sees the mechanics only referred to the electrical
side, ``(k, m, c, m_s) / phi²``, so ``phi`` needs a load of known Zm (or a tip velocity) and
the sphere's mass then needs a sweep without it as well as one with it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from wtml.physics.lumped import LumpedTransducer
from wtml.physics.measured import Sweep
from wtml.physics.twoport import cascade, tip_mass, ze_from_zm

LUMPED_PARAMETERS = ("c0", "phi", "k", "m", "c", "tan_delta")
"""The lumped transducer's parameters a fit may scale (``LumpedTransducer``'s fields)."""


@dataclass(frozen=True, eq=False)
class Measured:
    """One sweep: Ze with the tip free (``zm`` None) or under the known load ``zm`` (N·s/m,
    one per frequency), with the sphere mounted or not."""

    sweep: Sweep
    sphere: bool = True
    zm: np.ndarray | None = None


@dataclass(frozen=True)
class LumpedFit:
    """A lumped fit: ``factors`` of every free parameter (of the start's values), their
    ``standard_errors`` and ``covariance`` (factor units, in ``free``'s order), the reduced
    χ², and the fitted transducer and sphere radius (m)."""

    factors: dict[str, float]
    standard_errors: dict[str, float]
    covariance: np.ndarray
    reduced_chi2: float
    transducer: LumpedTransducer
    radius: float


def sphere_ze(tr: LumpedTransducer, omega: np.ndarray, sphere_mass: float,
              zm: np.ndarray | float = 0.0) -> np.ndarray:
    """Ze (Ω) of ``tr`` carrying ``sphere_mass`` kg at the tip (0: none) under the load
    ``zm`` (N·s/m; 0: free), ``omega.shape``."""
    t = tr.transduction_matrix(omega)
    if sphere_mass > 0:
        t = cascade(t, tip_mass(omega, sphere_mass))
    return ze_from_zm(t, zm)


def scaled(tr: LumpedTransducer, factors: Mapping[str, float]) -> LumpedTransducer:
    """``tr`` with each named parameter of :data:`LUMPED_PARAMETERS` times its factor."""
    return LumpedTransducer(**{p: getattr(tr, p) * float(factors.get(p, 1.0))
                               for p in LUMPED_PARAMETERS})


def fit_lumped(start: LumpedTransducer, radius: float, density: float,
               sweeps: list[Measured], free: Mapping[str, tuple[float, float]]) -> LumpedFit:
    """Fit factors of ``start`` (and of the sphere's ``radius``, m, at ``density`` kg/m³) to
    ``sweeps``; ``free``: the parameters of :data:`LUMPED_PARAMETERS` and ``sphere_radius``
    to fit, each with its factor range.

    Raises:
        ValueError: a parameter that is not one of those, or a range without factor 1.
    """
    names = list(free)
    for name, (lo, hi) in free.items():
        if name not in (*LUMPED_PARAMETERS, "sphere_radius"):
            raise ValueError(f"free: {name!r} is not one of "
                             f"{[*LUMPED_PARAMETERS, 'sphere_radius']}")
        if not 0 < lo < 1 < hi:
            raise ValueError(f"free: {name}: the range must be 0 < low < 1 < high, got "
                             f"[{lo:g}, {hi:g}]")

    def model(x: np.ndarray) -> tuple[LumpedTransducer, float]:
        f = dict(zip(names, map(float, x), strict=True))
        return scaled(start, f), radius * f.get("sphere_radius", 1.0)

    def residuals(x: np.ndarray) -> np.ndarray:
        tr, r = model(x)
        mass = density * 4 / 3 * np.pi * r**3
        parts = []
        for m in sweeps:
            s = m.sweep
            q = np.log(sphere_ze(tr, s.omega, mass if m.sphere else 0.0,
                                 0.0 if m.zm is None else m.zm) / s.ze)
            q = q / (s.sigma / np.sqrt(2))
            parts += [q.real, q.imag]
        return np.concatenate(parts)

    lo = np.array([free[n][0] for n in names])
    hi = np.array([free[n][1] for n in names])
    sol = least_squares(residuals, np.ones(len(names)), bounds=(lo, hi), x_scale="jac",
                        xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=2000)
    dof = max(len(sol.fun) - len(names), 1)
    chi2 = float(2 * sol.cost / dof)
    # the covariance from the eigenvalues of JᵀJ: a direction the data do not see (an
    # eigenvalue below 1e-13 of the largest) gives every parameter along it an infinite
    # standard error, where a pseudo-inverse would give it none
    vals, vecs = np.linalg.eigh(sol.jac.T @ sol.jac)
    seen = vals > 1e-13 * vals.max()
    cov = (vecs[:, seen] / vals[seen]) @ vecs[:, seen].T * max(chi2, 1.0)
    blind = np.any(np.abs(vecs[:, ~seen]) > 1e-2, axis=1)
    cov[blind, :] = cov[:, blind] = np.inf
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    tr, r = model(sol.x)
    return LumpedFit(dict(zip(names, map(float, sol.x), strict=True)),
                     dict(zip(names, map(float, se), strict=True)), cov, chi2, tr, r)


__all__ = ["LUMPED_PARAMETERS", "LumpedFit", "Measured", "fit_lumped", "scaled", "sphere_ze"]
