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
side, ``(k, m, c, m_s) / phi²``, so ``phi`` needs a load of known Zm (or a tip velocity), and
the sphere's mass needs a measurement without it (a sweep, or loads) as well as with it.
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
ANCHOR = 1e-3
"""Weight of the pull of each factor to 1, in residual units (the data's are σ-scaled)."""


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
    ``standard_errors`` and ``covariance`` (factor units, in ``free``'s order; infinite along
    what the data do not see, NaN for a parameter stopped on its range's bound), the reduced
    χ², the fitted transducer and sphere radius (m), and the parameters ``at_bound``."""

    factors: dict[str, float]
    standard_errors: dict[str, float]
    covariance: np.ndarray
    reduced_chi2: float
    transducer: LumpedTransducer
    radius: float
    at_bound: tuple[str, ...] = ()


def sphere_mass(radius: float, density: float) -> float:
    """kg of a sphere of ``radius`` m at ``density`` kg/m³."""
    return density * 4 / 3 * np.pi * radius**3


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

    last: dict[bytes, list] = {}

    def parts(x: np.ndarray) -> list[tuple[Measured, np.ndarray, np.ndarray]]:
        """Per sweep: q = log(Ze_model / Ze_measured) in units of σ/√2, and ∂q/∂x
        ``(n_freq, n_par)``, analytic: with u = Zm + Zt (+ jω m_s) and C = C0 (1 - j tanδ),
        Ze = u / (jωC u + φ²). The solver asks for the residuals and the Jacobian at the
        same x in turn: the last x's answer is kept."""
        key = np.asarray(x, float).tobytes()
        if key in last:
            return last[key]
        tr, r = model(x)
        mass = sphere_mass(r, density)
        out = []
        for m in sweeps:
            s, w = m.sweep, m.sweep.omega
            ms = mass if m.sphere else 0.0
            u = (0.0 if m.zm is None else m.zm) + tr.mechanical_impedance(w) + 1j * w * ms
            cap = tr.capacitance()
            d = 1j * w * cap * u + tr.phi**2
            scale = s.sigma / np.sqrt(2)
            du = 1 / u - 1j * w * cap / d  # ∂ log Ze / ∂u
            by = {"c": du, "m": du * 1j * w, "k": du / (1j * w),
                  "phi": -2 * tr.phi / d,
                  "c0": -1j * w * u / d * (1 - 1j * tr.tan_delta),
                  "tan_delta": -1j * w * u / d * (-1j * tr.c0),
                  "sphere_radius": du * 1j * w * 3 * ms}
            # ∂/∂(factor) = value at factor 1 × ∂/∂(value); the radius's: 3 m_s / factor
            jac = np.stack([by[n] * (getattr(start, n) if n != "sphere_radius"
                                     else 1 / x[names.index(n)]) for n in names], -1)
            out.append((m, np.log(u / d / s.ze) / scale, jac / scale))
        last.clear()
        last[key] = out
        return out

    def residuals(x: np.ndarray) -> np.ndarray:
        return np.concatenate([v for _, q, _ in parts(x) for v in (q.real, q.imag)])

    def jacobian(x: np.ndarray) -> np.ndarray:
        return np.concatenate([v for _, _, j in parts(x) for v in (j.real, j.imag)])

    # a faint pull of every factor to 1 (ANCHOR in units of the noise): along a direction
    # the data do not see the solver would otherwise wander to a bound; along a seen one it
    # moves the answer by less than 1e-9 of a standard error
    eye = ANCHOR * np.eye(len(names))
    lo = np.array([free[n][0] for n in names])
    hi = np.array([free[n][1] for n in names])
    sol = least_squares(lambda x: np.concatenate([residuals(x), ANCHOR * (x - 1)]),
                        np.ones(len(names)), jac=lambda x: np.vstack([jacobian(x), eye]),
                        bounds=(lo, hi), x_scale="jac", xtol=1e-14, ftol=1e-14, gtol=1e-14,
                        max_nfev=2000)
    data = residuals(sol.x)
    dof = max(len(data) - len(names), 1)
    chi2 = float(np.sum(data**2) / dof)
    at_bound = tuple(n for n, a in zip(names, sol.active_mask, strict=True) if a != 0)
    # the covariance from the eigenvalues of JᵀJ (the analytic Jacobian: a direction the data
    # do not see has an eigenvalue at rounding, ~1e-16 of the largest, where a seen one on
    # the shipped device is above 1e-8): every parameter with a share of such a direction
    # gets an infinite standard error, where a pseudo-inverse would give it a finite one
    at_fit = jacobian(sol.x)
    vals, vecs = np.linalg.eigh(at_fit.T @ at_fit)
    seen = vals > 1e-12 * vals.max()
    cov = (vecs[:, seen] / vals[seen]) @ vecs[:, seen].T * max(chi2, 1.0)
    blind = np.sqrt(np.sum(vecs[:, ~seen] ** 2, axis=1)) > 1e-6
    cov[blind, :] = cov[:, blind] = np.inf
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    se[[names.index(n) for n in at_bound]] = np.nan  # the range's answer, not the data's
    tr, r = model(sol.x)
    return LumpedFit(dict(zip(names, map(float, sol.x), strict=True)),
                     dict(zip(names, map(float, se), strict=True)), cov, chi2, tr, r,
                     at_bound)


__all__ = ["LUMPED_PARAMETERS", "LumpedFit", "Measured", "fit_lumped", "scaled", "sphere_mass",
           "sphere_ze"]
