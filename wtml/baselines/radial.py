"""Radial-location baselines, with the decoders' predict interface
(``predict(ze, ref) -> {"distance": m}``, ``ref`` the device's free reference Ze).

- :class:`PolynomialRadial`: the thesis's 9th-degree polynomials of d in Re Ze or in Im Ze
  at the first frequency (scikit-learn: standardise, polynomial features, least squares),
  by default of the ratio ``ze / ref`` instead (the contact's change against the device's
  free whisker), which removes the part of the device's spread the free Ze shows.
- :class:`InversionRadial`: the physics inversion on the nominal device (the preset), of the
  measurement corrected by the reference: ``ze × Ze_free(preset) / ref``, i.e. the ratio to
  the free Ze fitted by the preset's ratio. The forward model (the scene's beam model)
  is tabulated once on a grid of d and of the contact stiffness (the nuisance is estimated
  jointly); each measurement starts from the grid point of least relative misfit, then a
  damped, bounded least-squares solve in (d, 1/k) on the beam model itself
  (Levenberg–Marquardt, vectorised over measurements, clipped to the scene's ranges), with
  the weak Gaussian prior on ln k that the Cramér–Rao bound assumes. Each matters: in ln k
  the misfit is far from quadratic and undamped Gauss–Newton steps overshoot (measured: one
  such step leaves 0.45 µm); in the compliance 1/k the model is nearly linear; and for a stiff
  contact, whose k Ze hardly depends on, the prior keeps the solve well posed.
"""

from __future__ import annotations

import numpy as np
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import PolynomialFeatures, StandardScaler


class PolynomialRadial:
    """d as a polynomial of one part of Ze (or of ``ze / ref``) at the first frequency.

    Args:
        part: ``"real"`` or ``"imag"``.
        degree: polynomial degree (the thesis: 9).
        reference: of the ratio ``ze / ref`` (default); ``False``: of Ze itself, the thesis's
            polynomial (the nominal device assumed; ``ref`` is ignored).
    """

    def __init__(self, part: str, degree: int = 9, reference: bool = True) -> None:
        if part not in ("real", "imag"):
            raise ValueError(f"part must be 'real' or 'imag', got {part!r}")
        self.part, self.reference = part, reference
        self.name = (f"polynomial {degree} in {'Re' if part == 'real' else 'Im'} "
                     f"{'Ze/ref' if reference else 'Ze'}")
        self.model = make_pipeline(StandardScaler(), PolynomialFeatures(degree),
                                   LinearRegression())

    def _x(self, ze: np.ndarray, ref: np.ndarray) -> np.ndarray:
        z = np.asarray(ze)[:, 0] / (np.asarray(ref)[:, 0] if self.reference else 1.0)
        return (z.real if self.part == "real" else z.imag)[:, None]

    def fit(self, ze: np.ndarray, ref: np.ndarray, distance: np.ndarray) -> PolynomialRadial:
        self.model.fit(self._x(ze, ref), distance)
        return self

    def predict(self, ze: np.ndarray, ref: np.ndarray) -> dict[str, np.ndarray]:
        return {"distance": self.model.predict(self._x(ze, ref))}


class InversionRadial:
    """Physics inversion on the forward model (module docstring).

    Args:
        scene: a ``RadialScene``.
        step: grid spacing in m (default 2 µm).
        n_stiffness: grid points in the contact stiffness (log-spaced over its range).
        iterations: at most this many Levenberg–Marquardt iterations.
    """

    name = "physics inversion"

    def __init__(self, scene, step: float = 2e-6, n_stiffness: int = 9, iterations: int = 12
                 ) -> None:
        lo, hi = scene.distance_range_m()
        self.scene, self.transducer = scene, scene.transducer()
        self.d_range, self.lnk_range = (lo, hi), np.log(scene.contact.stiffness)
        self.grid_d = np.arange(lo, hi + step / 2, step)
        self.grid_k = np.geomspace(*scene.contact.stiffness, n_stiffness)
        d, k = np.meshgrid(self.grid_d, self.grid_k, indexing="ij")
        self.table = scene.ze_of(d.ravel(), k.ravel(), self.transducer)  # (n_table, n_freq)
        self.table_d, self.table_lnk = d.ravel(), np.log(k.ravel())
        self.iterations = iterations
        # the weak prior on ln k that the Cramér–Rao bound assumes (wtml.bench.bounds), in
        # units of one residual component's noise std, sigma/sqrt(2)
        self.lnk_mid, self.lnk_std = self.lnk_range.mean(), np.ptp(self.lnk_range) / np.sqrt(12)
        self.noise = max(scene.noise.ze_relative, 1e-12) / np.sqrt(2)
        self.free = scene.free_ze(self.transducer)  # the preset's, (n_freq,)

    def _residual(self, ze: np.ndarray, d: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Relative misfit (Re, Im per frequency) at distance ``d`` (m) and contact compliance
        ``c = 1/k`` (m/N), and the prior's term, ``(n, 2 n_freq + 1)``."""
        model = self.scene.ze_of(d, 1.0 / c, self.transducer)
        r = (ze - model) / model
        prior = self.noise * (-np.log(c) - self.lnk_mid) / self.lnk_std
        return np.concatenate([r.real, r.imag, prior[:, None]], -1)

    def start(self, ze: np.ndarray, chunk_bytes: int = 2**26) -> tuple[np.ndarray, np.ndarray]:
        """The grid point of least relative misfit: ``(d in m, ln k)``, each ``(n,)``, the
        misfits of as many measurements at a time as fit in ``chunk_bytes`` (64 MiB: the
        default grid's 14409 points take 115 kB per measurement; 4096 at a time held 0.47 GB).

        With ``w = 1/table``, the misfit ``Σ_f |ze_f w_f - 1|²`` expands to
        ``Σ_f |ze_f|² |w_f|² - 2 Re ze_f Re w_f + 2 Im ze_f Im w_f + 1``: one real matrix
        product of the measurements' ``(|ze|², Re ze, Im ze)`` with the table's
        ``(|w|², -2 Re w, 2 Im w)``."""
        w = 1.0 / self.table
        rows = np.concatenate([np.abs(w) ** 2, -2 * w.real, 2 * w.imag], -1).T  # (3 f, n_t)
        d, lnk = np.empty(len(ze)), np.empty(len(ze))
        chunk = max(1, chunk_bytes // (8 * len(self.table)))
        for s in range(0, len(ze), chunk):
            z = ze[s:s + chunk]
            best = np.argmin(np.concatenate([np.abs(z) ** 2, z.real, z.imag], -1) @ rows, -1)
            d[s:s + chunk], lnk[s:s + chunk] = self.table_d[best], self.table_lnk[best]
        return d, lnk

    def predict(self, ze: np.ndarray, ref: np.ndarray) -> dict[str, np.ndarray]:
        """``{"distance": (n,) m}``: the MAP of :meth:`solve`."""
        return {"distance": self.solve(ze, ref)[0]}

    def solve(self, ze: np.ndarray, ref: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """MAP in (d, c = 1/k) by Levenberg–Marquardt from :meth:`start`, vectorised over
        measurements, of ``ze × Ze_free / ref`` (module docstring) on the preset. In the
        compliance c, Ze is nearly linear (the contact is a Möbius function of k,
        ``1/(c + g)`` with the whisker's own compliance g ≫ c), where in ln k undamped steps
        overshoot; the bound's Gaussian prior on ln k keeps the flat direction
        of a stiff contact well posed. Each measurement has its own damping λ (scaled by
        diag(JᵀJ)): a step is kept only where it lowers the cost (then λ/3), else λ×4; steps
        are clipped to the scene's ranges. Stops when no measurement moves d by over 1 nm.

        Returns ``d`` (m) and ``c`` (m/N), each ``(n,)``, and the Laplace covariance of
        (d, c) there, ``(n, 2, 2)`` (the inverse Fisher information, the prior's included)."""
        ze = np.asarray(ze) * self.free / np.asarray(ref)
        d, lnk = self.start(ze)
        c, c_range = np.exp(-lnk), np.exp(-self.lnk_range[::-1])
        r = self._residual(ze, d, c)
        cost, lam = (r * r).sum(-1), np.full(len(ze), 1e-3)
        hd = 1e-9
        for _ in range(self.iterations):
            hc = 1e-4 * c
            jd = (self._residual(ze, d + hd, c) - r) / hd
            jc = (self._residual(ze, d, c + hc) - r) / hc[:, None]
            a11, a12, a22 = (jd * jd).sum(-1), (jd * jc).sum(-1), (jc * jc).sum(-1)
            b1, b2 = -(jd * r).sum(-1), -(jc * r).sum(-1)
            m11, m22 = a11 * (1 + lam), a22 * (1 + lam)
            det = m11 * m22 - a12**2
            safe = np.where(det > 0, det, 1.0)
            trial_d = np.clip(d + np.where(det > 0, (m22 * b1 - a12 * b2) / safe, 0.0),
                              *self.d_range)
            trial_c = np.clip(c + np.where(det > 0, (m11 * b2 - a12 * b1) / safe, 0.0),
                              *c_range)
            r_trial = self._residual(ze, trial_d, trial_c)
            cost_trial = (r_trial * r_trial).sum(-1)
            keep = cost_trial < cost
            moved = np.abs(np.where(keep, trial_d - d, 0.0)).max()
            d, c = np.where(keep, trial_d, d), np.where(keep, trial_c, c)
            r, cost = np.where(keep[:, None], r_trial, r), np.where(keep, cost_trial, cost)
            lam = np.where(keep, lam / 3, lam * 4)
            if moved < 1e-9:
                break
        hc = 1e-4 * c
        jd = (self._residual(ze, d + hd, c) - r) / hd
        jc = (self._residual(ze, d, c + hc) - r) / hc[:, None]
        a11, a12, a22 = (jd * jd).sum(-1), (jd * jc).sum(-1), (jc * jc).sum(-1)
        det = a11 * a22 - a12**2
        cov = self.noise**2 / det[:, None, None] * np.stack(
            [np.stack([a22, -a12], -1), np.stack([-a12, a11], -1)], -2)
        return d, c, cov



class BayesRadial:
    """The posterior mean of d under the radial scene's own prior and noise, the least
    mean-square error any method can reach on its records (the best achievable), by
    importance sampling.

    Prior: d uniform on the scene's range, ln k uniform on its stiffness range (in the
    compliance c = 1/k a density ∝ 1/c), the device the nominal one (a scene without a
    spread). Likelihood: each frequency's Ze is the beam model's ``z`` times ``1 + σn``, ``n``
    circular complex Gaussian (:func:`wtml.signals.noise.complex_noise`):
    ``log L = -Σ_f |ze - z|² / (σ|z|)² - 2 Σ_f ln|z|``. Proposal: a Student t (4 degrees of
    freedom) in (d, c) about :class:`InversionRadial`'s MAP with twice its Laplace std;
    ``draws`` per measurement, weights prior × likelihood / proposal. (A grid in (d, ln k)
    is biased here: at this noise the posterior of a soft contact is a ridge narrower than
    any affordable grid step in ln k.) :attr:`ess` holds the last call's effective sample
    size per measurement.

    Args:
        scene: a ``RadialScene`` without a device spread.
        draws: proposal draws per measurement.
        seed: the draws' generator seed (the same answers on every call).
    """

    name = "Bayes posterior mean"

    def __init__(self, scene, draws: int = 256, seed: int = 0, batch: int = 256) -> None:
        self.inversion = InversionRadial(scene)
        self.scene, self.draws, self.seed, self.batch = scene, draws, seed, batch
        self.sigma = max(scene.noise.ze_relative, 1e-12)
        self.c_range = np.exp(-self.inversion.lnk_range[::-1])
        self.ess = np.empty(0)

    def predict(self, ze: np.ndarray, ref: np.ndarray) -> dict[str, np.ndarray]:
        """``{"distance": (n,) m}`` for ``ze``, ``ref`` ``(n, n_freq)``."""
        ze = np.asarray(ze) * self.inversion.free / np.asarray(ref)
        d0, c0, cov = self.inversion.solve(ze, self.inversion.free[None])
        rng, nu = np.random.default_rng(self.seed), 4.0
        lo, hi = self.inversion.d_range
        out, ess = np.empty(len(ze)), np.empty(len(ze))
        for a in range(0, len(ze), self.batch):
            sl = slice(a, a + self.batch)
            b = len(ze[sl])
            chol = 2 * np.linalg.cholesky(cov[sl])  # (b, 2, 2)
            u = rng.standard_normal((b, self.draws, 2))
            scale = np.sqrt(nu / rng.chisquare(nu, (b, self.draws, 1)))
            x = np.stack([d0[sl], c0[sl]], -1)[:, None] + scale * np.einsum("bij,bmj->bmi",
                                                                            chol, u)
            d, c = x[..., 0], x[..., 1]
            inside = (d >= lo) & (d <= hi) & (c >= self.c_range[0]) & (c <= self.c_range[1])
            z = self.scene.ze_of(np.clip(d, lo, hi).ravel(),
                                 1 / np.clip(c, *self.c_range).ravel(),
                                 self.inversion.transducer).reshape(b, self.draws, -1)
            r = ze[sl, None] - z
            log_l = (-np.sum((r.real**2 + r.imag**2) / (self.sigma * np.abs(z)) ** 2, -1)
                     - 2 * np.log(np.abs(z)).sum(-1))
            # the t density of each draw up to its measurement's constant (which cancels):
            # the Mahalanobis distance of x - x0 = scale · L u is scale |u|
            q = -(nu + 2) / 2 * np.log1p((scale[..., 0] ** 2) * np.sum(u**2, -1) / nu)
            log_w = np.where(inside, log_l - np.log(np.abs(c)) - q, -np.inf)
            w = np.exp(log_w - log_w.max(1, keepdims=True))
            out[sl] = (w * d).sum(1) / w.sum(1)
            ess[sl] = w.sum(1) ** 2 / (w**2).sum(1)
        self.ess = ess
        return {"distance": out}
