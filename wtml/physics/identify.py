"""Identification: a device's free parameters from what the user measures (physics.md §13).

The model is any ``make(factors) -> BeamTransducer`` (a device file:
``lambda f: build(device, factors=f)``), ``factors`` being multipliers of named parameters
(``wtml.physics.beam_presets.device_parameters``), with an optional point mass at the tip (a
sphere). :func:`fit_device` adjusts the free ones, each within its stated factor range, by
bounded least squares (``scipy.optimize.least_squares``, parameters scaled to their ranges).

Residuals, each in units of its measurement's stated uncertainty (so that they are commensurate
and a correct statement gives a reduced χ² near 1):
- every sweep (free, clamped, each contact): ``log(Ze_model / Ze_measured)``, its real part
  (log|Ze|) and imaginary part (the phase, rad, wrapped), each divided by ``σ/√2`` where σ is
  the sweep's relative complex uncertainty (circular noise of ``E|n|² = σ²`` puts ``σ/√2`` on
  each); every point counts once, so a sweep of n points weighs n times one point;
- HUE(0): ``log(|HUE_model| / |HUE_measured|) / σ_hue`` (one term);
- tip velocity per volt: ``log(|V/E|_model / |V/E|_measured) / σ`` at each frequency.
The sign convention of T is not observable from impedances (physics.md §4), so the mechanical
terms compare magnitudes.

A resonance that starts far from the measured one leaves least squares in a local minimum; the
fit therefore runs first on the residuals smoothed along ln f by a Gaussian of widths
``smoothing`` (default 0.2, 0.06, 0.02: a misplaced peak's residual, smoothed wider than the
miss, pulls towards the right place), each stage starting from the last, then on the raw
residuals.

Standard errors: with J the Jacobian of the residuals in factor units at the solution (central
differences) and ``s² = Σr²/(m - n)`` the residual variance (the reduced χ²), the covariance is
``max(s², 1) (JᵀJ)⁻¹``: the residual variance, floored at the stated measurement uncertainty (a
model fitted to noise-free data of its own family has s² ≈ 0 and would otherwise claim any
parameter known; the floor keeps what the stated noise cannot resolve unidentifiable). A model
that cannot follow the data (another loss law, a missing mode) raises s² and the errors with
it. A parameter whose standard error exceeds the width of its range, or a singular JᵀJ, is
refused (:class:`IdentificationError`, naming the parameter).

Resonance table: resonances are peaks of the conductance Re(1/Ze), antiresonances peaks of the
resistance Re(Ze), found on the measured free sweep and on the fitted device's Ze on the same
grid (the same estimator on both); each peak's frequency is refined by a parabola through its
three highest points, its Q is f over its width at half its prominence
(``scipy.signal.peak_widths``), and each resonance's ``k² = (fa² - fr²)/fa²`` with the next
antiresonance above it. The cross-check independent of the beam model is scikit-rf's
``VectorFitting`` of the measured admittance (poles at the resonances) and impedance (poles at
the antiresonances): each pole ``p`` gives ``f = |p|/2π`` and ``Q = |p| / (2 |Re p|)``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import find_peaks, peak_widths

from wtml.physics.beam import BeamTransducer, PointMass
from wtml.physics.measured import Measurements, Sweep
from wtml.physics.twoport import drive_voltage, ze_from_zm


class IdentificationError(ValueError):
    """A fit that cannot be trusted: a parameter the measurements do not determine (its
    standard error wider than its range, or JᵀJ singular), or a bad request."""


Make = Callable[[dict[str, float]], BeamTransducer]
MISFIT = 10.0
"""A reduced χ² above this is reported as the model not following the measurements."""
TIP_MASS = "tip_mass"
"""The name of the tip mass's factor among the free parameters (not one of ``make``'s)."""


def with_tip_mass(tr: BeamTransducer, mass: float) -> BeamTransducer:
    """``tr`` with a point mass (kg) at its tip (a sphere; 0: ``tr`` itself)."""
    if not mass:
        return tr
    return BeamTransducer(tr.segments, tr.masses + (PointMass(tr.length, mass),), tr.tan_delta,
                          tr.rayleigh)


CHUNK = 2048
"""Frequencies per batched solve: the beam model holds ``(n_freq, n_dof, n_dof)`` complex
(~26 kB a frequency for the micro preset), so a long sweep is evaluated in chunks."""


def _chunked(fn, omega: np.ndarray) -> np.ndarray:
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    return np.concatenate([fn(omega[i:i + CHUNK]) for i in range(0, len(omega), CHUNK)])


def free_ze(tr: BeamTransducer, omega: np.ndarray) -> np.ndarray:
    """Ze (Ω) with the tip free, ``(n_freq,)``."""
    return _chunked(lambda w: ze_from_zm(tr.transduction_matrix(w), 0.0), omega)


def clamped_ze(tr: BeamTransducer, omega: np.ndarray) -> np.ndarray:
    """Ze (Ω) with the tip clamped, ``(n_freq,)``."""
    return _chunked(lambda w: ze_from_zm(tr.transduction_matrix(w), np.inf), omega)


def contact_ze(tr: BeamTransducer, omega: np.ndarray, distance: float,
               stiffness: float = np.inf) -> np.ndarray:
    """Free-tip Ze (Ω) with a pin at ``distance`` m from the tip of stiffness N/m (``inf``
    rigid), as the radial scenes compute it (``contact_transduction_matrix`` at
    ``length - distance``), ``(n_freq,)``."""
    where = np.array([tr.length - distance])
    return _chunked(lambda w: ze_from_zm(
        tr.contact_transduction_matrix(w, where, stiffness)[0], 0.0), omega)


def predict(tr: BeamTransducer, m: Measurements) -> dict:
    """The model's value of every measurement in ``m``: ``free``, ``clamped``, ``contacts``
    and ``loads`` (lists), ``hue0`` (m/V), ``tip_velocity`` (m/s/V)."""
    out: dict = {"free": free_ze(tr, m.free.omega)}
    if m.clamped is not None:
        out["clamped"] = clamped_ze(tr, m.clamped.omega)
    out["contacts"] = [contact_ze(tr, c.sweep.omega, c.distance, c.stiffness)
                       for c in m.contacts]
    out["loads"] = [ze_from_zm(tr.transduction_matrix(x.sweep.omega), x.zm) for x in m.loads]
    if m.hue0 is not None:
        out["hue0"] = tr.static_tip_displacement_per_volt()
    if m.tip_velocity is not None:
        t = tr.transduction_matrix(2 * np.pi * m.tip_velocity.frequency_hz)
        out["tip_velocity"] = drive_voltage(t, 0.0, 1.0)[1]
    return out


SMOOTHING_BINS = 512
"""The continuation smooths a sweep's residuals on at most this many bins along ln f."""


class _Smoother:
    """Residuals averaged into at most :data:`SMOOTHING_BINS` bins along ln f, then smoothed by
    row-normalised Gaussian weights of standard deviation ``width`` (ln f) between bins: a
    linear map of memory O(n + bins²) for a sweep of any length."""

    def __init__(self, frequency_hz: np.ndarray, width: float) -> None:
        from scipy.sparse import csr_matrix

        x = np.log(frequency_hz)
        n = len(x)
        bins = min(n, SMOOTHING_BINS)
        edges = np.linspace(x[0], x[-1], bins + 1)
        which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
        used = np.unique(which)
        which = np.searchsorted(used, which)
        counts = np.bincount(which)
        self.average = csr_matrix((1.0 / counts[which], (which, np.arange(n))),
                                  shape=(len(used), n))
        centre = self.average @ x
        w = np.exp(-0.5 * ((centre[:, None] - centre[None]) / width) ** 2)
        self.gauss = w / w.sum(1, keepdims=True)

    def __matmul__(self, r: np.ndarray) -> np.ndarray:
        return self.gauss @ (self.average @ r)


def _smoother(frequency_hz: np.ndarray, width: float) -> _Smoother:
    return _Smoother(frequency_hz, width)


def _sweeps(m: Measurements) -> list[tuple[str, Sweep]]:
    out = [("free", m.free)] + ([("clamped", m.clamped)] if m.clamped is not None else [])
    out += [(f"contact {i}", c.sweep) for i, c in enumerate(m.contacts)]
    return out + [(f"load {x.label}", x.sweep) for x in m.loads]


def _models(pred: dict, m: Measurements) -> list[np.ndarray]:
    """The model's Ze for each sweep of :func:`_sweeps`, in its order."""
    out = [pred["free"]] + ([pred["clamped"]] if m.clamped is not None else [])
    return out + pred["contacts"] + pred.get("loads", [])


def residuals(pred: dict, m: Measurements, smoothers: list | None = None) -> np.ndarray:
    """All residuals in units of their stated uncertainty (module docstring); ``smoothers``:
    one matrix per sweep (in :func:`_sweeps` order) applied to that sweep's residuals."""
    parts = []
    for k, ((_, sweep), model) in enumerate(zip(_sweeps(m), _models(pred, m), strict=True)):
        r = np.log(model / sweep.ze) / (sweep.sigma / np.sqrt(2))
        if smoothers is not None:
            r = smoothers[k] @ r
        parts += [r.real, r.imag]
    if m.hue0 is not None:
        parts.append(np.atleast_1d(np.log(abs(pred["hue0"]) / abs(m.hue0)) / m.hue0_sigma))
    if m.tip_velocity is not None:
        tv = m.tip_velocity
        parts.append(np.log(np.abs(pred["tip_velocity"]) / np.abs(tv.velocity_per_volt))
                     / tv.sigma)
    return np.concatenate(parts)


# ---------------------------------------------------------------------------- resonances


def _refine(f: np.ndarray, y: np.ndarray, i: int) -> float:
    if i == 0 or i == len(f) - 1:
        return float(f[i])
    x0, x1, x2 = f[i - 1:i + 2]
    y0, y1, y2 = y[i - 1:i + 2]
    den = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
    b = (x2**2 * (y0 - y1) + x1**2 * (y2 - y0) + x0**2 * (y1 - y2)) / den
    return float(-b / (2 * a)) if a < 0 else float(f[i])


def _peaks(f: np.ndarray, y: np.ndarray, prominence: float) -> list[tuple[float, float]]:
    """(frequency, Q) of each peak of the positive curve ``y`` whose prominence in ln y is at
    least ``prominence``."""
    y = np.maximum(y, np.max(np.abs(y)) * 1e-12)
    idx, _ = find_peaks(np.log(y), prominence=prominence)
    out = []
    if idx.size:
        _, _, left, right = peak_widths(y, idx, rel_height=0.5)
        grid = np.arange(len(f))
        for i, lo, hi in zip(idx, left, right, strict=True):
            fr = _refine(f, y, int(i))
            width = np.interp(hi, grid, f) - np.interp(lo, grid, f)
            out.append((fr, fr / width if width > 0 else math.inf))
    return out


def resonances(frequency_hz: np.ndarray, ze: np.ndarray, *, prominence: float = 0.5
               ) -> list[dict]:
    """Resonances (conductance peaks) and antiresonances (resistance peaks) of a sweep, with
    frequency (Hz), Q and, for each resonance, k² with the next antiresonance above it (module
    docstring); ``prominence`` in ln of the peak over its surroundings. Sorted by frequency."""
    f = np.asarray(frequency_hz, float)
    ze = np.asarray(ze, complex)
    rows = [{"kind": "resonance", "frequency_hz": fr, "q": q}
            for fr, q in _peaks(f, (1 / ze).real, prominence)]
    anti = [{"kind": "antiresonance", "frequency_hz": fa, "q": q}
            for fa, q in _peaks(f, ze.real, prominence)]
    rows = sorted(rows + anti, key=lambda r: r["frequency_hz"])
    for i, r in enumerate(rows):
        if r["kind"] == "resonance" and i + 1 < len(rows) and rows[i + 1]["kind"] != r["kind"]:
            fr, fa = r["frequency_hz"], rows[i + 1]["frequency_hz"]
            r["k2"] = (fa**2 - fr**2) / fa**2
    return rows


def vector_fit_poles(frequency_hz: np.ndarray, ze: np.ndarray, *, kind: str = "admittance",
                     n_complex: int = 2, n_real: int = 1) -> tuple[list[dict], list[str]]:
    """Poles of a rational fit (scikit-rf ``VectorFitting``) of the sweep's admittance 1/Ze
    (poles at the resonances) or impedance Ze (at the antiresonances): each pole with positive
    imaginary part as ``{"frequency_hz": |p|/2π, "q": |p|/(2|Re p|)}``, sorted, and the
    warnings scikit-rf raised (returned, not raised: the fit is a cross-check)."""
    import skrf
    from skrf.vectorFitting import VectorFitting

    f = np.asarray(frequency_hz, float)
    ze = np.asarray(ze, complex)
    ref = float(np.exp(np.mean(np.log(np.abs(ze)))))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        net = skrf.Network.from_z(ze[:, None, None], frequency=skrf.Frequency.from_f(f, unit="Hz"),
                                  z0=ref)
        vf = VectorFitting(net)
        vf.vector_fit(n_poles_real=n_real, n_poles_cmplx=n_complex, init_pole_spacing="log",
                      parameter_type="y" if kind == "admittance" else "z",
                      fit_proportional=kind == "admittance", fit_constant=True)
    poles = np.asarray(vf.poles)
    poles = poles[poles.imag > 0]
    rows = sorted(({"frequency_hz": float(abs(p) / (2 * np.pi)),
                    "q": float(abs(p) / (2 * abs(p.real))) if p.real else math.inf}
                   for p in poles), key=lambda r: r["frequency_hz"])
    notes = sorted({" ".join(str(w.message).split())[:160] for w in caught})
    return rows, notes


def device_poles(tr: BeamTransducer, kind: str = "resonance", count: int = 8) -> list[dict]:
    """The device's own poles, comparable with the rational fit's: of the admittance
    (``"resonance"``: electrodes shorted, ``det(K - ω²M) = 0`` with K complex) or of the
    impedance (``"antiresonance"``: open, ``K + ΘΘᵀ/Cp`` with Cp's dielectric loss); each
    ``{"frequency_hz": |p|/2π, "q": |p|/(2|Re p|)}`` with ``p = j√λ``, the lowest ``count``."""
    from scipy.linalg import eigvals

    k, m, theta = tr.matrices()
    if kind == "antiresonance":
        k = k + np.outer(theta, theta) / tr.capacitance
    lam = eigvals(k, m)
    lam = lam[np.isfinite(lam)]
    p = 1j * np.sqrt(lam.astype(complex))
    rows = sorted(({"frequency_hz": float(abs(q) / (2 * np.pi)),
                    "q": float(abs(q) / (2 * abs(q.real))) if q.real else math.inf}
                   for q in p), key=lambda r: r["frequency_hz"])
    return rows[:count]


def _nearest(rows: list[dict], kind: str, freq: float, tolerance: float = 0.2) -> dict | None:
    cands = [r for r in rows if r.get("kind", kind) == kind
             and abs(r["frequency_hz"] / freq - 1) < tolerance]
    return min(cands, key=lambda r: abs(r["frequency_hz"] / freq - 1), default=None)


def resonance_table(measured: Sweep, fitted_ze: np.ndarray, *, prominence: float = 0.5,
                    vector_fit: bool = True, device: BeamTransducer | None = None
                    ) -> tuple[list[dict], list[str]]:
    """One row per resonance and antiresonance of the measured free sweep: measured against
    the fitted device's Ze (same grid, same estimator: ``measured_*``, ``fitted_*``), the
    rational fit's pole of the measured sweep (``vf_*``) and the fitted ``device``'s own pole
    (``pole_*``, :func:`device_poles`: the same kind of quantity as ``vf_*``; the peak-width
    Q of a hysteretic resonance on a capacitive background is not its pole's Q); and the
    rational fit's warnings."""
    meas = resonances(measured.frequency_hz, measured.ze, prominence=prominence)
    fit = resonances(measured.frequency_hz, fitted_ze, prominence=prominence)
    poles: dict[str, list[dict]] = {"resonance": [], "antiresonance": []}
    notes: list[str] = []
    if vector_fit and meas:
        for kind, which in (("resonance", "admittance"), ("antiresonance", "impedance")):
            n = sum(r["kind"] == kind for r in meas)
            if n:
                try:
                    poles[kind], got = vector_fit_poles(measured.frequency_hz, measured.ze,
                                                        kind=which, n_complex=n + 1)
                except Exception as err:  # a cross-check: its failure is noted, not raised
                    got = [f"VectorFitting failed ({' '.join(str(err).split())[:120]})"]
                notes += [f"{which}: {w}" for w in got]
    table = []
    for r in meas:
        row = {"kind": r["kind"], "measured_hz": r["frequency_hz"], "measured_q": r["q"]}
        if "k2" in r:
            row["measured_k2"] = r["k2"]
        g = _nearest(fit, r["kind"], r["frequency_hz"])
        if g is not None:
            row |= {"fitted_hz": g["frequency_hz"], "fitted_q": g["q"]}
            if "k2" in g:
                row["fitted_k2"] = g["k2"]
        p = _nearest(poles[r["kind"]], r["kind"], r["frequency_hz"], tolerance=0.05)
        if p is not None:
            row |= {"vf_hz": p["frequency_hz"], "vf_q": p["q"]}
        if device is not None:
            q = _nearest(device_poles(device, r["kind"]), r["kind"], r["frequency_hz"],
                         tolerance=0.05)
            if q is not None:
                row |= {"pole_hz": q["frequency_hz"], "pole_q": q["q"]}
        table.append(row)
    return table, notes


def format_resonance_table(rows: list[dict]) -> str:
    """The resonance table as markdown."""
    def v(x, fmt):
        return "—" if x is None else format(x, fmt)

    lines = ["| kind | f meas (Hz) | f fit (Hz) | Q meas | Q fit | k² meas | k² fit | "
             "pole VF (Hz) | pole fit (Hz) | Q VF | Q pole fit |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['kind']} | {v(r.get('measured_hz'), '.3f')} | {v(r.get('fitted_hz'), '.3f')} "
            f"| {v(r.get('measured_q'), '.1f')} | {v(r.get('fitted_q'), '.1f')} | "
            f"{v(r.get('measured_k2'), '.4f')} | {v(r.get('fitted_k2'), '.4f')} | "
            f"{v(r.get('vf_hz'), '.3f')} | {v(r.get('pole_hz'), '.3f')} | "
            f"{v(r.get('vf_q'), '.1f')} | {v(r.get('pole_q'), '.1f')} |")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- the fit


@dataclass(frozen=True, eq=False)
class DeviceFit:
    """The result of :func:`fit_device`.

    Attributes:
        factors: every factor the fitted device is built with (the free ones fitted).
        free: the free parameters' ranges.
        standard_errors: of the free factors (factor units).
        covariance: of the free factors, in ``free``'s order.
        reduced_chi2: s², the residual variance in units of the stated uncertainties.
        cost: ½ Σ r² at the solution.
        transducer: the fitted device (with its tip mass).
        predicted: :func:`predict` of the fitted device.
        measurements: what was fitted.
        table: the resonance table (:func:`resonance_table`).
        notes: the rational fit's warnings and anything else worth stating.
        nominal: SI value and unit at factor 1 per parameter, where given.
        unidentifiable: the refusal lines (empty when every parameter is determined).
    """

    factors: dict[str, float]
    free: dict[str, tuple[float, float]]
    standard_errors: dict[str, float]
    covariance: np.ndarray
    reduced_chi2: float
    cost: float
    transducer: BeamTransducer
    predicted: dict
    measurements: Measurements
    table: list[dict]
    notes: list[str] = field(default_factory=list)
    nominal: dict[str, tuple[float, str]] = field(default_factory=dict)
    unidentifiable: list[str] = field(default_factory=list)

    def correlation(self) -> np.ndarray:
        """Correlation matrix of the free factors."""
        s = np.sqrt(np.diag(self.covariance))
        return self.covariance / np.outer(s, s)

    def residual_rms(self) -> dict[str, float]:
        """Per sweep: rms of |log(Ze_model/Ze_measured)| (relative), besides the tip terms."""
        m, p = self.measurements, self.predicted
        out = {name: float(np.sqrt(np.mean(np.abs(np.log(z / s.ze)) ** 2)))
               for (name, s), z in zip(_sweeps(m), _models(p, m), strict=True)}
        if m.hue0 is not None:
            out["hue0"] = float(abs(np.log(abs(p["hue0"]) / abs(m.hue0))))
        if m.tip_velocity is not None:
            out["tip_velocity"] = float(np.sqrt(np.mean(np.log(
                np.abs(p["tip_velocity"]) / np.abs(m.tip_velocity.velocity_per_volt)) ** 2)))
        return out

    def report(self) -> dict:
        """A JSON-able report: parameters (fit, standard error, range, SI where known),
        reduced χ², cost, residuals, the resonance table and the measurement files' sha256."""
        params = {}
        for name, (lo, hi) in self.free.items():
            entry = {"factor": self.factors[name], "standard_error": self.standard_errors[name],
                     "range": [lo, hi]}
            if name in self.nominal:
                value, unit = self.nominal[name]
                entry["si"] = {"value": value * self.factors[name],
                               "standard_error": abs(value) * self.standard_errors[name],
                               "unit": unit}
            params[name] = entry
        corr = self.correlation()
        names = list(self.free)
        return _finite({
            "parameters": params,
            "fixed": {k: v for k, v in self.factors.items() if k not in self.free},
            "correlation": {a: {b: float(corr[i, j]) for j, b in enumerate(names)}
                            for i, a in enumerate(names)},
            "reduced_chi2": self.reduced_chi2,
            "cost": self.cost,
            "residual_rms": self.residual_rms(),
            "resonances": self.table,
            "notes": self.notes,
            "unidentifiable": self.unidentifiable,
            "provenance": {"files": self.measurements.files()},
        })

    def plot(self, path: str | Path) -> Path:
        """Bode plot (PNG) of measured against fitted |Ze| and phase, every sweep."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        m, p = self.measurements, self.predicted
        fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
        for k, ((name, s), z) in enumerate(zip(_sweeps(m), _models(p, m), strict=True)):
            c = f"C{k % 10}"
            ax_m.loglog(s.frequency_hz, np.abs(s.ze), ".", color=c, ms=3,
                        label=f"{name} measured")
            ax_m.loglog(s.frequency_hz, np.abs(z), "-", color=c, lw=1, label=f"{name} fitted")
            ax_p.semilogx(s.frequency_hz, np.angle(s.ze, deg=True), ".", color=c, ms=3)
            ax_p.semilogx(s.frequency_hz, np.angle(z, deg=True), "-", color=c, lw=1)
        ax_m.set_ylabel("|Ze| (Ω)")
        ax_p.set_ylabel("phase Ze (°)")
        ax_p.set_xlabel("frequency (Hz)")
        ax_m.legend(fontsize=7, ncol=2)
        ax_m.set_title(f"device fit: reduced χ² {self.reduced_chi2:.3g}")
        for ax in (ax_m, ax_p):
            ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        path = Path(path)
        fig.savefig(path, dpi=120)
        plt.close(fig)
        return path


def _finite(x):
    """``x`` with every non-finite float (an unbounded Q, a singular covariance) as None, so
    that strict JSON holds it."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_finite(v) for v in x]
    if isinstance(x, float | np.floating):
        return float(x) if math.isfinite(x) else None
    return x


def _describe(m: Measurements) -> str:
    parts = ["a free sweep"] + ["a clamped sweep"] * (m.clamped is not None)
    parts += ["HUE(0)"] * (m.hue0 is not None) + ["tip velocity"] * (m.tip_velocity is not None)
    if m.contacts:
        parts.append(f"{len(m.contacts)} contact(s)")
    if m.loads:
        parts.append(f"{len(m.loads)} tip load(s)")
    return ", ".join(parts)


def _jacobian(fun, x: np.ndarray, step: np.ndarray) -> np.ndarray:
    cols = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = step[i]
        cols.append((fun(x + e) - fun(x - e)) / (2 * step[i]))
    return np.stack(cols, 1)


def fit_device(make: Make, free: Mapping[str, tuple[float, float]], measurements: Measurements,
               *, tip_mass: float = 0.0, fixed: Mapping[str, float] | None = None,
               start: Mapping[str, float] | None = None,
               nominal: Mapping[str, tuple[float, str]] | None = None,
               smoothing: tuple[float, ...] = (0.2, 0.06, 0.02), refuse: bool = True,
               prominence: float = 0.5, vector_fit: bool = True) -> DeviceFit:
    """Fit the free factors of ``make``'s device to ``measurements`` (module docstring).

    Args:
        make: factors -> BeamTransducer (the device at factor 1 is the starting point).
        free: ``{name: (low, high)}`` factor range of each free parameter (low < high, > 0).
        measurements: what was measured.
        tip_mass: kg at the tip (a sphere), added to every built device; ``"tip_mass"``
            among ``free`` (or ``fixed``) is a factor of it (a sphere's mass is known to a few
            % at best, and the fluid decoder is 36 % off for a 1 % larger sphere).
        fixed: factors held (default 1 for everything not free).
        start: starting factors of free parameters (default 1, clipped into the range).
        nominal: ``{name: (SI value at factor 1, unit)}`` for the report.
        smoothing: the continuation's Gaussian widths along ln f (() for none).
        refuse: raise :class:`IdentificationError` on an unidentifiable parameter (else list
            it in ``DeviceFit.unidentifiable``).
        prominence, vector_fit: for the resonance table.

    Raises:
        IdentificationError: a bad range, or (``refuse``) an unidentifiable parameter.
    """
    names = list(free)
    if not names:
        raise IdentificationError("free: name at least one parameter to fit")
    lo = np.array([free[n][0] for n in names], float)
    hi = np.array([free[n][1] for n in names], float)
    for n, a, b in zip(names, lo, hi, strict=True):
        if not (np.isfinite(a) and np.isfinite(b) and 0 < a < b):
            raise IdentificationError(f"free.{n}: range must be 0 < low < high (factors), got "
                                      f"({a:g}, {b:g})")
    held = dict(fixed or {})
    both = sorted(set(held) & set(names))
    if both:
        raise IdentificationError(f"fixed.{both[0]}: is also free; a parameter is one or the "
                                  "other")
    x0 = np.array([(start or {}).get(n, 1.0) for n in names], float)
    x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

    if TIP_MASS in names and not tip_mass > 0:
        raise IdentificationError(f"free.{TIP_MASS}: a factor of tip_mass, which is "
                                  f"{tip_mass:g} kg; give the tip mass to scale")

    def device(x: np.ndarray) -> BeamTransducer:
        factors = held | dict(zip(names, map(float, x), strict=True))
        scale = factors.pop(TIP_MASS, 1.0)
        return with_tip_mass(make(factors), tip_mass * scale)

    m = measurements
    smoothers_all = [[_smoother(s.frequency_hz, w) for _, s in _sweeps(m)] for w in smoothing]

    def fun(x: np.ndarray, smoothers=None) -> np.ndarray:
        with np.errstate(all="ignore"):
            r = residuals(predict(device(x), m), m, smoothers)
        # a lossless resonance exactly on a measured frequency: a large finite miss, so that
        # the solver steps away instead of stopping on NaN
        return np.nan_to_num(r, nan=1e12, posinf=1e12, neginf=-1e12)

    x = x0
    for sm in smoothers_all:
        x = least_squares(fun, x, bounds=(lo, hi), x_scale=hi - lo, kwargs={"smoothers": sm},
                          xtol=1e-6, ftol=1e-6, method="trf").x
    sol = least_squares(fun, x, bounds=(lo, hi), x_scale=hi - lo, xtol=1e-10, ftol=1e-10,
                        gtol=1e-10, method="trf")
    x = sol.x
    r = fun(x)
    dof = max(r.size - len(x), 1)
    s2 = float(r @ r / dof)
    jac = _jacobian(fun, x, 1e-4 * (hi - lo))
    u, sv, vt = np.linalg.svd(jac * (hi - lo), full_matrices=False)  # range-scaled columns
    problems = []
    if sv[-1] <= sv[0] * 1e-13:
        worst = names[int(np.argmax(np.abs(vt[-1])))]
        problems.append(f"{worst}: JᵀJ is singular (condition {sv[0] / max(sv[-1], 1e-300):.2g})"
                        f": not identifiable from {_describe(m)} together with "
                        f"{', '.join(n for n in names if n != worst)}")
        cov = np.full((len(x), len(x)), np.inf)
    else:
        scaled = (vt.T / sv**2) @ vt  # (J_s^T J_s)^-1 in range units
        cov = max(s2, 1.0) * scaled * np.outer(hi - lo, hi - lo)
    se = np.sqrt(np.abs(np.diag(cov)))
    if not problems:
        ratio = se / (hi - lo)
        for i in np.argsort(-ratio):
            if ratio[i] > 1:
                problems.append(
                    f"{names[i]}: standard error {se[i]:.3g} exceeds its range "
                    f"{lo[i]:g}–{hi[i]:g} (width {hi[i] - lo[i]:.3g}, factors): not "
                    f"identifiable from {_describe(m)}; fix it, narrow its range or measure "
                    "what shows it (contacts at known places show the whisker)")
    misfit = (f" (and the model misses these measurements: reduced χ² {s2:.3g}, expected ≈1 "
              "at the stated uncertainty)") if s2 > MISFIT else ""
    problems = [p + misfit for p in problems]
    if problems and refuse:
        raise IdentificationError(problems[0])
    tr = device(x)
    pred = predict(tr, m)
    table, notes = resonance_table(m.free, pred["free"], prominence=prominence,
                                   vector_fit=vector_fit, device=tr)
    factors = held | {n: float(v) for n, v in zip(names, x, strict=True)}
    nominal = dict(nominal or {}) | ({TIP_MASS: (tip_mass, "kg")} if tip_mass else {})
    at_bound = [n for n, v, a, b in zip(names, x, lo, hi, strict=True)
                if min(v - a, b - v) < 1e-6 * (b - a)]
    if at_bound:
        notes = notes + [f"{n}: at the edge of its range" for n in at_bound]
    if s2 > MISFIT:
        notes = notes + [f"reduced χ² {s2:.3g}: the model does not follow the measurements to "
                         "their stated uncertainty (a loss law, a mode or a parameter it does "
                         "not have, or the uncertainty understated); the standard errors are "
                         "scaled by it"]
    return DeviceFit(factors, {n: (float(a), float(b)) for n, a, b in
                               zip(names, lo, hi, strict=True)},
                     {n: float(v) for n, v in zip(names, se, strict=True)}, cov, s2,
                     float(sol.cost), tr, pred, m, table, notes, nominal, problems)


def nominal_values(device) -> dict[str, tuple[float, str]]:
    """SI value and unit at factor 1 of each parameter of a beam device (a
    :class:`~wtml.devices.BeamDevice`, a shipped name or a file's path): lengths and
    thicknesses in m (the bimorph's free length and PZT layer; a round whisker's radius, a
    square one's side), moduli in Pa, |d31| in m/V, loss factor and tanδ unitless."""
    from wtml.physics.beam_presets import beam_device

    d = beam_device(device)
    b, w = d.bimorph, d.whisker
    out = {"bimorph.length": (b.free_length, "m"), "bimorph.thickness": (b.t_piezo, "m"),
           "bimorph.modulus": (1 / d.piezo.s11e, "Pa"),
           "whisker.length": (w.length, "m"), "whisker.thickness": (w.size, "m"),
           "whisker.modulus": (w.material.modulus, "Pa"),
           "loss_factor": (d.losses.loss_factor, "1"), "tan_delta": (d.losses.tan_delta, "1"),
           "whisker.loss_factor": (d.losses.loss_factor if d.losses.whisker is None
                                   else d.losses.whisker, "1"),
           "coupling": (abs(d.piezo.d31), "m/V")}
    if d.block is not None:
        k = d.block
        out |= {"block.length": (k.length, "m"), "block.thickness": (k.thickness, "m"),
                "block.modulus": (k.material.modulus, "Pa")}
    if b.t_substrate > 0:
        out["substrate.modulus"] = (b.substrate.modulus, "Pa")
    return out


def with_segment_losses(tr: BeamTransducer, losses: Mapping[str, float]) -> BeamTransducer:
    """``tr`` with the loss factor of the named segments replaced (a device whose loss model
    differs from a single structural loss factor, e.g. a lossier whisker)."""
    segs = tuple(replace(s, loss_factor=losses.get(s.name, s.loss_factor))
                 for s in tr.segments)
    return BeamTransducer(segs, tr.masses, tr.tan_delta, tr.rayleigh)


__all__ = ["TIP_MASS", "DeviceFit", "IdentificationError", "clamped_ze", "contact_ze",
           "device_poles", "fit_device", "format_resonance_table", "free_ze", "predict",
           "nominal_values", "resonance_table", "resonances", "residuals", "vector_fit_poles",
           "with_segment_losses", "with_tip_mass"]
