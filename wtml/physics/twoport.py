"""Two-port algebra of the transduction matrix (physics.md §2).

T maps the mechanical port (force ``F`` applied by the transducer to the load, tip velocity
``V``) to the electrical port (voltage ``E``, current ``I``)::

    [E, I]^T = T @ [F, V]^T,    T = [[t11, t12], [t21, t22]],    det T = 1 (reciprocity).

Every function takes T of shape ``(..., 2, 2)`` and impedances or port variables of shape
``(...)``, broadcast against each other (typically ``(n_loads, n_freq)`` against
``(n_freq, 2, 2)``). Values are complex128 phasors with time dependence ``e^{jωt}``, in SI:
Ω for ``Ze``, N·s/m for ``Zm``, V, A, N, m/s for the port variables.

Free (``Zm = 0``) and clamped (``Zm = inf``) loads are exact: the bilinear maps switch to the
admittance form ``Ym = 1/Zm`` where ``|Zm| > 1``, so no intermediate overflows for any
``|Zm|`` up to ``inf``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "cascade",
    "det_error",
    "displacement_per_charge",
    "displacement_per_voltage",
    "drive_velocity",
    "drive_voltage",
    "efficiency",
    "flat_parts",
    "flat_views",
    "electrical_from_mechanical",
    "electrical_power",
    "elements",
    "force_per_charge",
    "force_per_voltage",
    "mechanical_from_electrical",
    "mechanical_power",
    "tip_mass",
    "ym_from_ze",
    "ze_from_zm",
    "zm_from_ze",
]


def elements(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split T of shape ``(..., 2, 2)`` into ``t11, t12, t21, t22``, each of shape ``(...)``."""
    t = np.asarray(t)
    if t.shape[-2:] != (2, 2):
        raise ValueError(f"T must have shape (..., 2, 2), got {t.shape}")
    return t[..., 0, 0], t[..., 0, 1], t[..., 1, 0], t[..., 1, 1]


def flat_parts(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T of shape ``(..., 2, 2)`` as the exported graphs take it: real and imaginary parts,
    float32, each ``(..., 4)`` in the order (t11, t12, t21, t22)."""
    re, im = flat_views(t)
    return re.astype(np.float32), im.astype(np.float32)


def flat_views(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`flat_parts` as float64 views of ``t``'s own memory (no copy for a complex128
    T whose last two axes are contiguous), for a caller that casts them later in pieces."""
    flat = np.asarray(t, dtype=complex)
    if flat.shape[-2:] != (2, 2):
        raise ValueError(f"T must have shape (..., 2, 2), got {flat.shape}")
    flat = flat.reshape(*flat.shape[:-2], 4)
    return flat.real, flat.imag


def _bilinear(a, b, c, d, z) -> np.ndarray:
    """``(a z + b) / (c z + d)`` for any ``z`` in [0, inf], without overflow.

    Where ``|z| > 1`` it evaluates ``(a + b y) / (c + d y)`` with ``y = 1/z`` (``y = 0`` at
    ``z = inf``), so the free and clamped limits ``b/d`` and ``a/c`` come out exactly.
    """
    z = np.asarray(z)
    large = np.abs(z) > 1.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        y = np.where(np.isinf(z), 0.0, 1.0 / np.where(large, z, 1.0))
        direct = (a * z + b) / (c * z + d)
        via_admittance = (a + b * y) / (c + d * y)
    return np.where(large, via_admittance, direct)


def ze_from_zm(t: np.ndarray, zm) -> np.ndarray:
    """Electrical impedance seen at the port for a mechanical load (Eq. 3.14).

    ``Ze = (t11 Zm + t12) / (t21 Zm + t22)``; free load ``Zm = 0`` gives ``t12/t22``,
    clamped ``Zm = inf`` gives ``t11/t21``.

    Args:
        t: transduction matrix, shape ``(..., 2, 2)``.
        zm: load impedance in N·s/m, shape broadcastable with ``t[..., 0, 0]``.

    Returns:
        ``Ze`` in Ω, the broadcast shape.
    """
    t11, t12, t21, t22 = elements(t)
    return _bilinear(t11, t12, t21, t22, zm)


def zm_from_ze(t: np.ndarray, ze) -> np.ndarray:
    """Mechanical load impedance from the electrical impedance (Eq. 3.15).

    ``Zm = (t22 Ze - t12) / (t11 - t21 Ze)``. The map is ill-conditioned near the clamped
    value ``Ze -> t11/t21``: its sensitivity is ``dZm/dZe = 1/(t11 - t21 Ze)^2`` (det T = 1),
    and where the denominator is exactly zero the result is ``inf`` (a clamped tip). Use
    :func:`ym_from_ze` to work in admittance there.

    Args:
        t: transduction matrix, shape ``(..., 2, 2)``.
        ze: electrical impedance in Ω, broadcastable with ``t[..., 0, 0]``.

    Returns:
        ``Zm`` in N·s/m, the broadcast shape.
    """
    t11, t12, t21, t22 = elements(t)
    ze = np.asarray(ze)
    num = t22 * ze - t12
    den = t11 - t21 * ze
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den == 0, np.inf + 0j, num / den)


def ym_from_ze(t: np.ndarray, ze) -> np.ndarray:
    """Mechanical load admittance ``Ym = 1/Zm`` in m/(N·s), finite at the clamped limit.

    ``Ym = (t11 - t21 Ze) / (t22 Ze - t12)``; ``inf`` at the free value ``Ze = t12/t22``.
    Shapes as in :func:`zm_from_ze`.
    """
    t11, t12, t21, t22 = elements(t)
    ze = np.asarray(ze)
    num = t11 - t21 * ze
    den = t22 * ze - t12
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den == 0, np.inf + 0j, num / den)


def mechanical_from_electrical(t: np.ndarray, e, i) -> tuple[np.ndarray, np.ndarray]:
    """Force and velocity at the tip from voltage and current (Eq. 3.8, the sensing form).

    ``F = (t22 E - t12 I) / det T``, ``V = (-t21 E + t11 I) / det T``; with det T = 1 this is
    Eq. 3.8. Dividing by the actual determinant keeps it the exact inverse of
    :func:`electrical_from_mechanical` for a T that is only nearly reciprocal.

    Args:
        t: shape ``(..., 2, 2)``.
        e: voltage phasor in V, broadcastable with ``t[..., 0, 0]``.
        i: current phasor in A, same.

    Returns:
        ``(F, V)`` in N and m/s.
    """
    t11, t12, t21, t22 = elements(t)
    det = t11 * t22 - t12 * t21
    return (t22 * e - t12 * i) / det, (-t21 * e + t11 * i) / det


def electrical_from_mechanical(t: np.ndarray, f, v) -> tuple[np.ndarray, np.ndarray]:
    """Voltage and current from tip force and velocity (Eq. 3.1).

    Args:
        t: shape ``(..., 2, 2)``.
        f: force in N, broadcastable with ``t[..., 0, 0]``.
        v: velocity in m/s, same.

    Returns:
        ``(E, I)`` in V and A.
    """
    t11, t12, t21, t22 = elements(t)
    return t11 * f + t12 * v, t21 * f + t22 * v


def drive_voltage(t: np.ndarray, zm, e) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Port variables when the transducer is driven by a voltage ``e`` against a load ``zm``.

    Args:
        t: shape ``(..., 2, 2)``.
        zm: load impedance in N·s/m (0 free, inf clamped), broadcastable.
        e: voltage phasor in V, broadcastable.

    Returns:
        ``(F, V, I)`` in N, m/s and A.
    """
    t11, t12, t21, t22 = elements(t)
    f = e * _bilinear(1.0, 0.0, t11, t12, zm)  # F/E = Zm / (t11 Zm + t12)
    v = e * _bilinear(0.0, 1.0, t11, t12, zm)  # V/E = 1 / (t11 Zm + t12)
    return f, v, t21 * f + t22 * v


def drive_velocity(t: np.ndarray, v, termination: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Port variables when the tip is driven at velocity ``v`` with the electrical port
    ``"open"`` (``I = 0``) or ``"short"`` (``E = 0``), as in the open/short calibration.

    Returns:
        ``(F, E, I)`` in N, V and A, broadcast against ``t[..., 0, 0]``.
    """
    t11, t12, t21, t22 = elements(t)
    if termination == "open":
        f = -t22 * v / t21
    elif termination == "short":
        f = -t12 * v / t11
    else:
        raise ValueError(f"termination must be 'open' or 'short', got {termination!r}")
    e, i = electrical_from_mechanical(t, f, v)
    # the terminated variable is zero by construction; set it exactly, not to rounding
    if termination == "open":
        return f, e, np.zeros_like(i)
    return f, np.zeros_like(e), i


def cascade(*ts: np.ndarray) -> np.ndarray:
    """Two-ports in series, transducer side first: ``cascade(T_w, T_s) = T_w @ T_s``.

    Each argument has shape ``(..., 2, 2)``; leading dimensions broadcast.
    """
    if not ts:
        raise ValueError("cascade needs at least one two-port")
    out = np.asarray(ts[0], dtype=complex)
    for t in ts[1:]:
        out = np.matmul(out, np.asarray(t, dtype=complex))
    return out


def tip_mass(omega, mass) -> np.ndarray:
    """Two-port of a rigid mass ``ms`` carried at the tip: ``[[1, jω ms], [0, 1]]``.

    Args:
        omega: angular frequency in rad/s, shape ``(...)``.
        mass: mass in kg, broadcastable with ``omega``.

    Returns:
        shape ``broadcast(omega, mass).shape + (2, 2)``, complex128, det = 1 exactly.
    """
    omega, mass = np.broadcast_arrays(np.asarray(omega, float), np.asarray(mass, float))
    if np.any(mass < 0):
        raise ValueError(f"tip mass must be >= 0 kg, got min {mass.min()}")
    t = np.zeros(omega.shape + (2, 2), dtype=complex)
    t[..., 0, 0] = 1.0
    t[..., 1, 1] = 1.0
    t[..., 0, 1] = 1j * omega * mass
    return t


def det_error(t: np.ndarray) -> np.ndarray:
    """Health figure ``|det T - 1|`` (0 for a reciprocal T), shape ``(...)``.

    Its rounding floor is about ``eps (|t11 t22| + |t12 t21|)``, which for SI elements of a
    real transducer (``t11 ~ 1e5``, ``t22 ~ 1``) is ~1e-11, not 1e-16.
    """
    t11, t12, t21, t22 = elements(t)
    return np.abs(t11 * t22 - t12 * t21 - 1.0)


def electrical_power(e, i) -> np.ndarray:
    """Complex electrical power ``Pe = ½ E I*`` in W (real part: mean power drawn)."""
    return 0.5 * np.asarray(e) * np.conj(i)


def mechanical_power(f, v) -> np.ndarray:
    """Complex mechanical power ``Pm = ½ F V*`` in W (real part: mean power into the load)."""
    return 0.5 * np.asarray(f) * np.conj(v)


def efficiency(t: np.ndarray, zm) -> np.ndarray:
    """Electromechanical efficiency ``Re Pm / Re Pe`` under a load ``zm`` (N·s/m).

    Independent of the drive level; 0 for free, clamped and purely reactive loads.
    Shape: the broadcast of ``t[..., 0, 0]`` and ``zm``.
    """
    f, v, i = drive_voltage(t, zm, 1.0)
    return mechanical_power(f, v).real / electrical_power(1.0, i).real


def force_per_voltage(t: np.ndarray, zl) -> np.ndarray:
    """Actuator transfer ``F/E = 1/(t11 + t12/ZL)`` in N/V (Eq. 3.19); 0 for a free load."""
    t11, t12, _, _ = elements(t)
    return _bilinear(1.0, 0.0, t11, t12, zl)


def displacement_per_voltage(t: np.ndarray, zl, omega) -> np.ndarray:
    """Actuator transfer ``U/E = 1/(jω (t11 ZL + t12))`` in m/V, ``U = V/(jω)``; 0 clamped."""
    t11, t12, _, _ = elements(t)
    return _bilinear(0.0, 1.0, t11, t12, zl) / (1j * np.asarray(omega))


def force_per_charge(t: np.ndarray, zl, omega) -> np.ndarray:
    """Sensor transfer ``F/Q = jω/(t21 + t22/ZL)`` in N/C, ``Q = I/(jω)``; 0 for a free load."""
    _, _, t21, t22 = elements(t)
    return 1j * np.asarray(omega) * _bilinear(1.0, 0.0, t21, t22, zl)


def displacement_per_charge(t: np.ndarray, zl) -> np.ndarray:
    """Sensor transfer ``U/Q = 1/(t21 ZL + t22)`` in m/C; 0 for a clamped load."""
    _, _, t21, t22 = elements(t)
    return _bilinear(0.0, 1.0, t21, t22, zl)
