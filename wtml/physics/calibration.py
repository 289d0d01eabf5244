"""Calibration of the transduction matrix (physics.md §4; thesis §3.4, §4.3).

Three methods, each returning a :class:`Calibration` (T on a frequency grid, with diagnostics):

- :func:`calibrate_least_squares`: electrical data only, under n >= 4 loads of known Zm
  (Eqs. 3.42–3.47). Per frequency, each load gives one complex row
  ``Zm x1 + Zm Ze x2 + x3 = Ze`` with ``x1 = t11/t22``, ``x2 = -t21/t22``, ``x3 = t12/t22``
  (a clamped load, ``Zm = inf``, gives the row ``x1 + Ze x2 = 0``). Rows are weighted so that
  a relative error of Ze weighs the same in each (a second pass, with x2 from the first), and
  the columns are scaled to unit norm before an SVD solve (``Zm ~ 1e-3`` against
  ``Ze ~ 1e5–1e9`` would otherwise give condition numbers up to 1e16 and silent garbage); the
  condition number of the scaled system and the residual are kept per frequency, and a load
  set whose condition number exceeds ``max_condition`` is refused. Then
  ``t22 = ±1/sqrt(x1 + x2 x3)`` (det T = 1), ``t11 = x1 t22``, ``t21 = -x2 t22``, ``t12 = x3 t22``.
- :func:`calibrate_free_clamped`: ``t12 = E/V``, ``t22 = I/V`` with a free tip (F = 0);
  ``t11 = E/F``, ``t21 = I/F`` with a clamped tip (V = 0) (Eqs. 3.2–3.5).
- :func:`calibrate_open_short`: tip driven mechanically; ``t21 = -V/E``, ``t22 = F/E`` with the
  electrical port open (I = 0), ``t11 = V/I``, ``t12 = -F/I`` shorted (E = 0) (Eqs. 3.38–3.41).

The sign rule. Impedances cannot tell T from -T (both give the same Ze for every Zm), so the
least-squares method fixes the sign by a rule; the choice flips the signs of F and V that the
calibration reports, never Zm:

- ``"continuity"`` (default): at the first grid frequency ``Re t11 > 0``; at each following
  frequency the sign for which ``Re(t22 conj(t22_prev)) >= 0``, so T is continuous along the
  grid (the grid must resolve T's phase, as any swept calibration does).
- ``"re_t11_positive"``: ``Re t11 > 0`` at every frequency independently.

``t11 = E/F|V=0`` is the inverse blocked force per volt. Below the first resonance of the
clamped-tip structure it is nearly real, and positive for the poling in which a positive voltage
pushes the tip outward, which is the convention here (the lumped model has ``t11 = 1/φ > 0``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wtml.constants import SignRule
from wtml.physics import twoport

__all__ = [
    "Calibration",
    "CalibrationError",
    "calibrate_free_clamped",
    "calibrate_least_squares",
    "calibrate_open_short",
]

_FORMAT = "wtml.calibration/1"


class CalibrationError(ValueError):
    """A load set or measurement that cannot give a trustworthy T."""


@dataclass(frozen=True)
class Calibration:
    """A calibrated transduction matrix on a frequency grid.

    Attributes:
        t: T, shape ``(n_freq, 2, 2)``, complex128.
        omega: the grid in rad/s, shape ``(n_freq,)``; NaN where it was not given.
        condition: condition number of the column-scaled least-squares system per frequency,
            shape ``(n_freq,)`` (NaN for the direct methods).
        residual: RMS over loads of the weighted residuals, in units of relative Ze error,
            per frequency, shape ``(n_freq,)``: about ``sqrt((n_loads - 3)/n_loads)`` times
            the relative noise of Ze when the loads' Zm are right (NaN for direct methods).
        method: ``"least_squares"``, ``"free_clamped"`` or ``"open_short"``.
        sign_rule: the rule that fixed the overall sign (``"measured"`` for direct methods).
        n_loads: loads used (0 for the direct methods).
    """

    t: np.ndarray
    omega: np.ndarray
    condition: np.ndarray
    residual: np.ndarray
    method: str
    sign_rule: str
    n_loads: int = 0

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=complex)
        if t.ndim != 3 or t.shape[1:] != (2, 2):
            raise ValueError(f"t must have shape (n_freq, 2, 2), got {t.shape}")
        n = t.shape[0]
        for name in ("omega", "condition", "residual"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "t", t)

    @property
    def n_freq(self) -> int:
        return self.t.shape[0]

    def det_error(self) -> np.ndarray:
        """``|det T - 1|`` per frequency, shape ``(n_freq,)``."""
        return twoport.det_error(self.t)

    def zm_from_ze(self, ze) -> np.ndarray:
        """Load impedance in N·s/m from Ze in Ω of shape ``(..., n_freq)``."""
        return twoport.zm_from_ze(self.t, ze)

    def ze_from_zm(self, zm) -> np.ndarray:
        """Ze in Ω for loads in N·s/m of shape ``(..., n_freq)``."""
        return twoport.ze_from_zm(self.t, zm)

    def mechanical_from_electrical(self, e, i) -> tuple[np.ndarray, np.ndarray]:
        """``(F, V)`` in N and m/s from E in V and I in A, shapes ``(..., n_freq)``."""
        return twoport.mechanical_from_electrical(self.t, e, i)

    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` (arrays and a JSON header, no pickle); returns the path."""
        path = Path(path)
        header = {"format": _FORMAT, "method": self.method, "sign_rule": self.sign_rule,
                  "n_loads": self.n_loads}
        with open(path, "wb") as fh:
            np.savez(fh, t=self.t, omega=self.omega, condition=self.condition,
                     residual=self.residual, header=np.array(json.dumps(header)))
        return path

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a file written by :meth:`save` (refuses pickled content and other formats)."""
        with np.load(Path(path), allow_pickle=False) as data:
            missing = {"t", "omega", "condition", "residual", "header"} - set(data.files)
            if missing:
                raise ValueError(f"{path} is not a wtml calibration: missing {sorted(missing)}")
            header = json.loads(str(data["header"]))
            if header.get("format") != _FORMAT:
                raise ValueError(f"{path}: format {header.get('format')!r}, expected {_FORMAT!r}")
            return cls(t=data["t"], omega=data["omega"], condition=data["condition"],
                       residual=data["residual"], method=header["method"],
                       sign_rule=header["sign_rule"], n_loads=int(header["n_loads"]))


def _omega_or_nan(omega, n_freq: int) -> np.ndarray:
    if omega is None:
        return np.full(n_freq, np.nan)
    omega = np.broadcast_to(np.asarray(omega, dtype=float), (n_freq,)).copy()
    if np.any(~np.isfinite(omega) | (omega <= 0)):
        raise ValueError("omega must be finite and > 0 rad/s")
    return omega


def _fix_sign(t22: np.ndarray, x1: np.ndarray, sign_rule: SignRule) -> np.ndarray:
    """Choose the sign of ``t22`` (shape ``(n_freq,)``) by the documented rule."""
    sign = np.where((x1 * t22).real >= 0, 1.0, -1.0)  # Re t11 = Re(x1 t22) > 0
    if sign_rule == "re_t11_positive":
        return sign * t22
    if sign_rule != "continuity":
        raise ValueError(f"sign_rule must be 'continuity' or 're_t11_positive', got {sign_rule!r}")
    out = t22.copy()
    out[0] *= sign[0]
    for k in range(1, len(out)):
        if (out[k] * np.conj(out[k - 1])).real < 0:
            out[k] = -out[k]
    return out


def _solve_scaled(a: np.ndarray, b: np.ndarray, row_weight: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares ``min |W (A x - b)|`` per frequency with unit-norm columns.

    Args:
        a: ``(n_freq, n_loads, 3)``; b: ``(n_freq, n_loads)``; row_weight: ``(n_freq, n_loads)``.

    Returns:
        ``x`` of shape ``(n_freq, 3)`` and the condition number of the weighted, column-scaled
        system, shape ``(n_freq,)`` (inf when it is rank deficient).
    """
    aw, bw = a * row_weight[..., None], b * row_weight
    scale = np.linalg.norm(aw, axis=1)  # (n_freq, 3)
    if np.any(scale == 0):
        raise CalibrationError("a column of the calibration system is zero: "
                               "the load set has no free, finite or clamped variety")
    u, s, vh = np.linalg.svd(aw / scale[:, None, :], full_matrices=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        condition = np.where(s[:, -1] > 0, s[:, 0] / s[:, -1], np.inf)
        y = np.einsum("fji,fj->fi", np.conj(vh), np.einsum("fji,fj->fi", np.conj(u), bw) / s)
    return y / scale, condition


def _check_condition(condition: np.ndarray, max_condition: float) -> None:
    worst = int(np.argmax(np.where(np.isnan(condition), np.inf, condition)))
    if not condition[worst] <= max_condition:
        raise CalibrationError(
            f"loads too alike to calibrate: condition number {condition[worst]:.3g} at "
            f"frequency index {worst} exceeds max_condition={max_condition:.3g}; use loads "
            "whose impedances differ more (e.g. contact points farther apart) or raise "
            "max_condition knowing that T's relative error is about condition x noise")


def calibrate_least_squares(zm, ze, omega=None, *, max_condition: float = 1e4,
                            sign_rule: SignRule = "continuity") -> Calibration:
    """Calibrate T from electrical impedances measured under known loads.

    Args:
        zm: known load impedances in N·s/m, shape ``(n_loads, n_freq)`` or ``(n_loads,)`` for
            one frequency; 0 is the free load, ``inf`` a clamped tip.
        ze: measured electrical impedances in Ω, same shape.
        omega: the frequency grid in rad/s, shape ``(n_freq,)`` (recorded, not used).
        max_condition: refuse when the column-scaled system's condition number exceeds this
            at any frequency. The relative error of T is roughly the condition number times
            the relative noise of Ze, so 1e4 leaves two digits at 1e-6 noise.
        sign_rule: ``"continuity"`` or ``"re_t11_positive"`` (module docstring).

    Returns:
        A :class:`Calibration` with det T = 1 by construction.

    Raises:
        CalibrationError: fewer than 4 loads, non-finite Ze, or loads too alike (the message
            names the condition number, the frequency index and the threshold).
    """
    zm = np.asarray(zm, dtype=complex)
    ze = np.asarray(ze, dtype=complex)
    if zm.ndim == 1 and ze.ndim == 1:  # one frequency
        zm, ze = zm[:, None], ze[:, None]
    if zm.shape != ze.shape or zm.ndim != 2:
        raise CalibrationError(
            f"zm and ze must both have shape (n_loads, n_freq); got {zm.shape} and {ze.shape}")
    n_loads, n_freq = zm.shape
    if n_loads < 4:
        raise CalibrationError(f"least-squares calibration needs >= 4 loads, got {n_loads}")
    if not np.all(np.isfinite(ze)):
        raise CalibrationError("ze contains NaN or inf")
    if np.any(np.isnan(zm)):
        raise CalibrationError("zm contains NaN")

    clamped = np.isinf(zm)
    zm_f = np.where(clamped, 0.0, zm)
    # rows (n_freq, n_loads, 3): [Zm, Zm Ze, 1] = Ze, or [1, Ze, 0] = 0 for a clamped tip
    a = np.stack([np.where(clamped, 1.0, zm_f),
                  np.where(clamped, ze, zm_f * ze),
                  np.where(clamped, 0.0, 1.0)], axis=-1).transpose(1, 0, 2)
    b = np.where(clamped, 0.0, ze).T
    # rows are weighted to equal noise: a relative error δ on Ze moves row i's residual by
    # |Ze_i (Zm_i x2 - 1)| δ (|Ze_i x2| δ for a clamped row); x2 comes from a first solve
    # with rows of equal norm
    equal_rows = 1.0 / np.linalg.norm(np.concatenate([a, b[..., None]], -1), axis=-1)
    x, condition = _solve_scaled(a, b, equal_rows)
    _check_condition(condition, 1 / np.finfo(float).eps)  # only a rank-deficient set fails here
    ze_t = ze.T
    gain = np.abs(ze_t) * np.where(clamped.T, np.abs(x[:, 1:2]), np.abs(zm_f.T * x[:, 1:2] - 1))
    weight = 1.0 / np.maximum(gain, np.finfo(float).tiny)
    x, condition = _solve_scaled(a, b, weight)
    _check_condition(condition, max_condition)
    # weighted residuals are in units of relative Ze error: their RMS estimates the noise
    residual = np.sqrt(np.mean(np.abs(weight * (np.einsum("fij,fj->fi", a, x) - b)) ** 2,
                               axis=1))
    x1, x2, x3 = x[:, 0], x[:, 1], x[:, 2]
    t22 = _fix_sign(1.0 / np.sqrt(x1 + x2 * x3), x1, sign_rule)
    t = np.empty((n_freq, 2, 2), dtype=complex)
    t[:, 0, 0] = x1 * t22
    t[:, 0, 1] = x3 * t22
    t[:, 1, 0] = -x2 * t22
    t[:, 1, 1] = t22
    return Calibration(t=t, omega=_omega_or_nan(omega, n_freq), condition=condition,
                       residual=residual, method="least_squares", sign_rule=sign_rule,
                       n_loads=n_loads)


def _direct(t11, t12, t21, t22, omega, method: str) -> Calibration:
    t11, t12, t21, t22 = np.broadcast_arrays(*(np.atleast_1d(np.asarray(x, dtype=complex))
                                               for x in (t11, t12, t21, t22)))
    if t11.ndim != 1:
        raise ValueError(f"direct calibration takes phasors of shape (n_freq,), got {t11.shape}")
    t = np.stack([np.stack([t11, t12], -1), np.stack([t21, t22], -1)], -2)
    if not np.all(np.isfinite(t)):
        raise CalibrationError(f"{method}: a measured quantity is zero or not finite")
    nan = np.full(t.shape[0], np.nan)
    return Calibration(t=t, omega=_omega_or_nan(omega, t.shape[0]), condition=nan,
                       residual=nan, method=method, sign_rule="measured")


def calibrate_free_clamped(free, clamped, omega=None) -> Calibration:
    """Direct method 1: free tip and clamped tip, electrical drive.

    Args:
        free: ``(E, I, V)`` phasors with the tip free (F = 0), each shape ``(n_freq,)``.
        clamped: ``(E, I, F)`` phasors with the tip clamped (V = 0), each ``(n_freq,)``.
        omega: the grid in rad/s, ``(n_freq,)``.
    """
    e_f, i_f, v_f = (np.asarray(x, dtype=complex) for x in free)
    e_c, i_c, f_c = (np.asarray(x, dtype=complex) for x in clamped)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _direct(e_c / f_c, e_f / v_f, i_c / f_c, i_f / v_f, omega, "free_clamped")


def calibrate_open_short(open_, short, omega=None) -> Calibration:
    """Direct method 2: tip driven in velocity, electrical port open then shorted.

    Args:
        open_: ``(F, V, E)`` phasors with the port open (I = 0), each shape ``(n_freq,)``.
        short: ``(F, V, I)`` phasors with the port shorted (E = 0), each ``(n_freq,)``.
        omega: the grid in rad/s, ``(n_freq,)``.
    """
    f_o, v_o, e_o = (np.asarray(x, dtype=complex) for x in open_)
    f_s, v_s, i_s = (np.asarray(x, dtype=complex) for x in short)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _direct(v_s / i_s, -f_s / i_s, -v_o / e_o, f_o / e_o, omega, "open_short")
