"""A second, independent simulator of the onset scene: the held-out "device" of the tests.

Written from physics.md (§3, §9, §10, §12) alone; it shares with the production stepper
(:mod:`wtml.physics.modal`) only the beam's matrices (``build(preset).matrices()``: K complex
with the loss, M, Θ, and the clamped capacitance with its tanδ) and the scene's definition
(drive, lead-in, sampling, labelling, acquisition). Everything else is its own:

- **Modal reduction.** Its own eigen-solve ``Re K φ = ω² M φ`` (mass-normalised), the n
  lowest kept; the truncated modes' static correction by the mode-acceleration method,
  ``G_res = (Re K)⁻¹ − Φ Ω⁻² Φᵀ`` giving ``a_r, β_r, δ_r``; modal viscous damping
  ``ζ_i = η_i/2`` with ``η_i = φ_iᵀ Im K φ_i / ω_i²``. Equations (F: the force the tip
  applies to the wall, compressive > 0)::

      q'' + 2ζΩ q' + Ω² q = φθ E − φb F,   u = φb·q − a_r F + β_r E,
      Q = φθ·q − β_r F + (Cp + δ_r) E,     I = Q' + I_loss.

- **Dielectric loss** at constant tanδ: the loss current ``Σ_k ω_k Cp tanδ E_k(t)`` over the
  drive's tones (whisk and probe, each with the lead-in's ramp), not one conductance.
- **Time integration** (default, :func:`_fixed_step`): TR-BDF2 (a trapezoidal stage to
  ``t + γh``, then BDF2 to ``t + h``, γ = 2 − √2: second order, L-stable) at a fixed step
  ``h = dt/substeps`` (default dt/16), from rest at the lead-in's start, one record at a time
  (compiled by numba). Each implicit stage is solved exactly: per mode the stage's q, q' are
  affine in the stage's force, so the modal tip ``u_m`` and its rate are too, and the law
  closes one scalar equation for F (closed form for the linear wall, Newton for the others).
  The drive is the exact continuous E(t) at every stage (not sampled or held). A free tip
  touches when the would-be touch function crosses 0 (``u_m − g``, for the linear wall
  ``min(u_m − g, k (u_m − g) + c u_m')``), an engaged one leaves when the force (linear wall)
  or ``u_m − g`` (the others) falls through 0; a step that crosses is cut at the crossing,
  located to 1e-13 of the step by the Illinois method on the step's length (each trial the
  integrator's own step), the regime switched and the rest of the step taken. Against
  solve_ivp on a 2 s record of the shipped scene (32 events): 3.6e-5 rms of the current at
  dt/16 (1.4e-4 at dt/8, 2.3e-6 at dt/64: second order), the same events and onsets. CPU
  per 2 s record: 0.45 s (linear), 0.6 s (power), 0.5 s (mount–Hertz), 1.0 s
  (Hunt–Crossley), after a one-off compilation of ~10 s (cached on disk).
- **Cross-check** (``method="DOP853"`` or ``"Radau"``, :func:`_simulate_batch`):
  :func:`scipy.integrate.solve_ivp` with events for touch and release (each restarting the
  integrator with that record in the other regime). Records are independent blocks of one
  system (the vectorised right-hand side is what makes Python integration affordable).
  DOP853, and Radau with the exact block Jacobian wherever a force is a stiff state (the
  damped linear wall, below). Tolerances: ``rtol`` (default 1e-9; its change from 1e-7 to
  1e-10 is 1.5e-8 rms) and ``atol = rtol ×`` (0.1 µm of tip motion per mode, its rate,
  1 µN of force), scipy's RMS norm over the batch; ``max_step`` one sample interval.
  107 s of CPU per 2 s record at rtol 1e-9 (61 s at 1e-7). The lead-in is simulated and
  dropped by both.

Against the production stepper (:mod:`wtml.physics.modal`, :mod:`wtml.physics.contact`) on
2 s records of the shipped scene, the whisk tone removed (where the two dielectric losses
differ): 9.6e-4 rms free, 3–7e-3 with the linear wall, 1.6–11e-3 with the smooth laws;
every onset and detachment within one sample. The gap is the production's step: at twice
and four times its sample rate it falls to 2.4e-4 and 6.0e-5 free (its drive held
first-order: second order), to 2.0e-3 and 1.1e-3 with the linear wall (switched on the
samples, up to a step late: first order) and by 4 per halving with the smooth laws (the
force linear over the step: second order).

Contact laws (δ = u − g the penetration, k_ref the record's ``stiffness``, physics.md §12):

- ``linear``: ``F = k δ + c δ'`` while compressive (k = stiffness, c = damping). With the
  residual compliance ``a_r`` the tip's u contains F, so for c > 0 the force is a state:
  ``c a_r F' = k (u_m − g) + c u_m' − (1 + k a_r) F`` with ``u_m = φb·q + β_r E``
  (time constant ~1 µs: stiff, hence L-stable TR-BDF2, or Radau for solve_ivp), restarted at
  0 at each touch; for c = 0 it is algebraic, ``F = k (u_m − g)/(1 + k a_r)``.
- ``power``: ``F = K δ^n``, ``K = k_ref δ_ref^(1−n)/n`` (tangent k_ref at δ_ref);
  parameters ``exponent`` n, ``reference_m`` δ_ref.
- ``hunt_crossley``: ``F = K δ^n (1 + α δ')`` clipped at 0, K as the power law; parameters
  ``exponent``, ``reference_m``, ``alpha_s_per_m`` α. Its series relaxation with a_r has the
  time constant ``α a_r F`` (≲ 1e-8 s here, and 0 at touch, where the exact form is 0/0), so
  δ' is taken on the elastic branch, ``δ' = u_m'/(1 + a_r K n δ^(n−1))``; the current leaves
  out the rate of the damping part (``β_r d(K δ^n α δ')/dt``, ~α δ' ≈ 1e-3 of the contact
  term).
- ``mount_hertz``: a linear mount in series with a Hertz contact,
  ``δ = F/k_m + (F/K_h)^(2/3)``, set by the tangent ``dF/dδ = k_ref`` at ``δ = δ_ref`` and
  the share ``m`` (``mount_fraction``, in (0, 1)) of that tangent compliance in the mount:
  ``k_m = k_ref/m``; then ``F_ref = k_ref δ_ref/(1.5 − 0.5 m)``, the Hertz penetration at
  F_ref ``s = 1.5 (1 − m) δ_ref/(1.5 − 0.5 m)`` and ``K_h = F_ref / s^1.5``. m → 1 is the
  linear wall k_ref; m → 0 the power law with n = 1.5.

For every law the touch event is the gap crossing ``u = g`` (with the would-be force
compressive); release is the force turning tensile (δ back to 0 for the elastic laws).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.integrate import solve_ivp
from scipy.linalg import eigh
from scipy.sparse import block_diag

from wtml.physics.beam import BeamTransducer
from wtml.physics.validation import check_range
from wtml.signals.excitation import lead_in
from wtml.signals.noise import quantize

LAWS = ("linear", "power", "hunt_crossley", "mount_hertz")
METHODS = ("trbdf2", "DOP853", "Radau")
LAW_DEFAULTS: dict[str, dict[str, float]] = {
    "linear": {},
    "power": {"exponent": 1.5, "reference_m": 1e-6},
    "hunt_crossley": {"exponent": 1.5, "reference_m": 1e-6, "alpha_s_per_m": 0.3},
    "mount_hertz": {"reference_m": 1e-6, "mount_fraction": 0.5},
}
"""Each law's parameters and their defaults (δ_ref 1 µm: a typical penetration of the
shipped scene's walls; n 1.5: Hertz; α 0.3 s/m; half the compliance in the mount)."""
LAW_RANGES: dict[str, tuple[float, float, str]] = {
    "exponent": (1.0, 1.5, ""), "reference_m": (1e-9, 1e-4, "m"),
    "alpha_s_per_m": (0.0, 10.0, "s/m"), "mount_fraction": (1e-3, 0.999, ""),
}

_UNUSED = {"exponent": 1.0, "reference_m": 1e-6, "alpha_s_per_m": 0.0, "mount_fraction": 0.5}
"""Placeholders of the parameters a law does not take."""


@dataclass(frozen=True)
class ModalModel:
    """The beam reduced to its n lowest modes with static correction (module docstring).

    Attributes:
        omega: Ω, rad/s, ``(n,)``.   zeta: ζ = η/2, ``(n,)``.
        tip: φb, m/√kg, ``(n,)``.    coupling: φθ, N/(V·√kg), ``(n,)``.
        a_r (m/N), beta_r (m/V), delta_r (F): the truncated modes' static residuals.
        capacitance: Cp (real), F.   tan_delta: dielectric loss tangent.
    """

    omega: np.ndarray
    zeta: np.ndarray
    tip: np.ndarray
    coupling: np.ndarray
    a_r: float
    beta_r: float
    delta_r: float
    capacitance: float
    tan_delta: float

    @classmethod
    def from_beam(cls, beam: BeamTransducer, n_modes: int) -> ModalModel:
        """The ``n_modes`` lowest modes of ``beam`` (tip free, electrodes shorted)."""
        k, m, theta = beam.matrices()
        check_range("n_modes", n_modes, 1, len(theta))
        w2, phi = eigh(k.real, m, subset_by_index=[0, n_modes - 1])  # Φᵀ M Φ = 1
        eta = np.einsum("ij,jk,ki->i", phi.T, k.imag, phi) / w2
        b = np.zeros(len(theta))
        b[-2] = 1.0
        tip, coupling = phi.T @ b, phi.T @ theta
        flex = np.linalg.solve(k.real, np.column_stack([b, theta]))  # (Re K)⁻¹ [b, Θ]
        cp = complex(beam.capacitance)
        return cls(omega=np.sqrt(w2), zeta=eta / 2, tip=tip, coupling=coupling,
                   a_r=float(flex[-2, 0] - np.sum(tip**2 / w2)),
                   beta_r=float(flex[-2, 1] - np.sum(tip * coupling / w2)),
                   delta_r=float(theta @ flex[:, 1] - np.sum(coupling**2 / w2)),
                   capacitance=cp.real, tan_delta=-cp.imag / cp.real)

    def with_coupling(self, scale: float) -> ModalModel:
        """The device with its piezo coupling Θ scaled by ``scale`` (φθ, β_r by it, δ_r by
        its square; Cp unchanged)."""
        return dataclasses.replace(self, coupling=self.coupling * scale,
                                   beta_r=self.beta_r * scale, delta_r=self.delta_r * scale**2)

    def static_tip_displacement_per_volt(self) -> float:
        """HUE(0) = ``Σ φb φθ/Ω² + β_r``, m/V."""
        return float(np.sum(self.tip * self.coupling / self.omega**2) + self.beta_r)

    def transduction_matrix(self, omega) -> np.ndarray:
        """T(ω) with a free tip (physics.md §3 from the modal forms ``a, β, δ``; the dielectric
        ``Cp (1 − j tanδ)``), shape ``omega.shape + (2, 2)``, det T = 1."""
        w = np.asarray(omega, dtype=float)[..., None]
        h = 1 / (self.omega**2 - w**2 + 2j * self.zeta * self.omega * w)
        a = np.sum(self.tip**2 * h, -1) + self.a_r
        beta = np.sum(self.tip * self.coupling * h, -1) + self.beta_r
        delta = (self.capacitance * (1 - 1j * self.tan_delta)
                 + np.sum(self.coupling**2 * h, -1) + self.delta_r)
        jw = 1j * w[..., 0]
        return np.stack([np.stack([a / beta, 1 / (jw * beta)], -1),
                         np.stack([jw * (a * delta - beta**2) / beta, delta / beta], -1)], -2)


@dataclass(frozen=True)
class ContactLaw:
    """The wall law of a batch of B records (module docstring): ``stiffness`` k or k_ref
    (N/m), ``damping`` c (N·s/m, linear law only) and the law's parameters
    (:data:`LAW_DEFAULTS`), each ``(B,)``."""

    law: str
    stiffness: np.ndarray
    damping: np.ndarray
    exponent: np.ndarray
    reference_m: np.ndarray
    alpha_s_per_m: np.ndarray
    mount_fraction: np.ndarray

    @property
    def gain(self) -> np.ndarray:
        """K of the power and Hunt–Crossley laws, N/m^n, ``(B,)``."""
        n = self.exponent
        return self.stiffness * self.reference_m ** (1 - n) / n

    def hertz(self) -> tuple[np.ndarray, np.ndarray]:
        """``(k_m N/m, K_h N/m^1.5)`` of the mount–Hertz law, each ``(B,)``."""
        m, k, d = self.mount_fraction, self.stiffness, self.reference_m
        f_ref = k * d / (1.5 - 0.5 * m)
        s = 1.5 * (1 - m) * d / (1.5 - 0.5 * m)
        return k / m, f_ref / s**1.5

    @property
    def stiff_state(self) -> bool:
        """Whether the force is a state (the linear wall with damping)."""
        return self.law == "linear" and bool(np.any(self.damping > 0))

    def force(self, over, over_rate, a_r: float) -> tuple[np.ndarray, np.ndarray]:
        """The force (N) and its rate (N/s) of the algebraic laws from the modal tip's
        overshoot ``over = u_m − g`` (m, > 0 in contact) and its rate (m/s), each ``(B,)``
        or ``(B, n_t)``; ``a_r`` the residual compliance in series."""
        over = np.maximum(over, 0.0)
        col = (slice(None),) + (None,) * (np.ndim(over) - 1)
        if self.law == "linear":
            s = (self.stiffness / (1 + self.stiffness * a_r))[col]
            return s * over, s * over_rate
        if self.law == "mount_hertz":
            k_m, k_h = (x[col] for x in self.hertz())
            comp = (a_r + 1 / k_m) * k_h
            x = np.minimum(np.sqrt(over), np.cbrt(over / comp))  # above the root
            for _ in range(60):  # convex, increasing: Newton from above converges
                step = (comp * x**3 + x**2 - over) / (3 * comp * x**2 + 2 * x + 1e-300)
                x = x - step
                if np.all(np.abs(step) <= 1e-14 * x):
                    break
            return k_h * x**3, 3 * k_h * x / (3 * comp * x + 2) * over_rate
        n, k = self.exponent[col], self.gain[col]
        delta = _power_root(over, a_r * k, n)
        stiff = n * k * delta ** (n - 1)
        rate = over_rate / (1 + a_r * stiff)  # δ' on the elastic branch
        if self.law == "power":
            return k * delta**n, stiff * rate
        k = k * np.maximum(1 + self.alpha_s_per_m[col] * rate, 0.0)
        delta = _power_root(over, a_r * k, n)
        stiff = n * k * delta ** (n - 1)
        return k * delta**n, stiff * over_rate / (1 + a_r * stiff)


def _power_root(over, c, n):
    """δ ≥ 0 with ``δ + c δ^n = over`` (c ≥ 0, n ≥ 1): convex and increasing, so Newton
    from δ = over (above the root) converges monotonically."""
    d = np.array(over, dtype=float)
    for _ in range(60):
        step = (d + c * d**n - over) / (1 + c * n * d ** (n - 1))
        d = d - step
        if np.all(np.abs(step) <= 1e-14 * d):
            break
    return d


class _Drive:
    """The scene's drive ``E = −AL cos ωL t + AH sin ωH t`` (V) with the lead-in's raised
    cosine from ``−lead_s`` to 0, at any instant t (s): ``tones(t)`` gives the whisk and
    probe parts and their rates (the same as :func:`~wtml.signals.excitation.lead_in` at the
    samples)."""

    def __init__(self, scene):
        d = scene.drive
        self.al, self.ah, self.lead = d.whisk_v, d.probe_v, d.lead_s
        self.wl, self.wh = 2 * math.pi * d.whisk_hz, 2 * math.pi * d.probe_hz

    def __call__(self, t: float) -> tuple[float, float]:
        """E (V) and dE/dt (V/s) at the scalar t."""
        e = -self.al * math.cos(self.wl * t) + self.ah * math.sin(self.wh * t)
        de = self.al * self.wl * math.sin(self.wl * t) + self.ah * self.wh * math.cos(self.wh * t)
        if t >= 0:
            return e, de
        x = (t + self.lead) / self.lead
        if x <= 0:
            return 0.0, 0.0
        r, dr = 0.5 - 0.5 * math.cos(math.pi * x), 0.5 * math.pi / self.lead * math.sin(math.pi * x)
        return e * r, de * r + e * dr

    def tones(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Whisk part, its rate, probe part, its rate at the instants t, each ``t.shape``."""
        el, dl = lead_in(t, -self.al * np.cos(self.wl * t), self.al * self.wl * np.sin(self.wl * t),
                         self.lead)
        eh, dh = lead_in(t, self.ah * np.sin(self.wh * t), self.ah * self.wh * np.cos(self.wh * t),
                         self.lead)
        return el, dl, eh, dh


def _simulate_batch(model: ModalModel, scale: np.ndarray, law: ContactLaw, gap: np.ndarray,
                    drive: _Drive, times: np.ndarray, rtol: float, method: str
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """B records from rest, side by side in one system of independent blocks (the vectorised
    right-hand side is what makes Python integration affordable): the states ``[q, q', F]``
    at ``times`` ``(B, 2n+1, n_t)``, the regimes there (engaged, ``(B, n_t)``) and each
    record's number of events ``(B,)``.

    One event function serves the batch: each record's own (touch while free, the force or
    the penetration falling through 0 while engaged, negated) is < 0 between its events, so
    their maximum crosses 0 upward at the first event of any record; that record switches and
    the integration restarts. DOP853 while no record's force is a stiff state, else Radau
    with the block-diagonal Jacobian."""
    n, bsz = len(model.omega), len(gap)
    tip, a_r = model.tip, model.a_r
    cpl, br = model.coupling * scale[:, None], model.beta_r * scale  # (B, n), (B,)
    k, c = law.stiffness, law.damping
    dim = 2 * n + 1
    free = np.zeros((dim, dim))
    free[:n, n:2 * n] = np.eye(n)
    free[n:2 * n, :n] = -np.diag(model.omega**2)
    free[n:2 * n, n:2 * n] = -np.diag(2 * model.zeta * model.omega)
    stiff = law.stiff_state
    tau = c * a_r if stiff else np.ones(bsz)
    if stiff:  # c a_r F' = k (u_m − g) + c u_m' − (1 + k a_r) F, and −φb F in q''
        eng = np.repeat(free[None], bsz, 0)
        eng[:, n:2 * n, -1] = -tip
        eng[:, -1, :n] = (k / tau)[:, None] * tip
        eng[:, -1, n:2 * n] = (c / tau)[:, None] * tip
        eng[:, -1, -1] = -(1 + k * a_r) / tau
    engaged = np.zeros(bsz, bool)

    def overshoot(y, e, de):
        return y[:, :n] @ tip + br * e - gap, y[:, n:2 * n] @ tip + br * de

    def rhs(t, flat):
        y = flat.reshape(bsz, dim)
        e, de = drive(t)
        out = y @ free.T
        out[:, n:2 * n] += cpl * e
        over, rate = overshoot(y, e, de)
        if stiff:
            force = np.where(engaged, y[:, -1], 0.0)
            out[:, -1] = np.where(engaged, (k * over + c * rate - (1 + k * a_r) * force) / tau,
                                  0.0)
        else:
            force = np.where(engaged, law.force(over, rate, a_r)[0], 0.0)
        out[:, n:2 * n] -= force[:, None] * tip
        return out.ravel()

    def signs(t, flat):
        """Each record's event function, < 0 between its events, ``(B,)``."""
        y = flat.reshape(bsz, dim)
        e, de = drive(t)
        over, rate = overshoot(y, e, de)
        touch = np.minimum(over, k * over + c * rate) if law.law == "linear" else over
        release = y[:, -1] if stiff else over
        return np.where(engaged, -release, touch)

    def event(t, flat):
        return float(np.max(signs(t, flat)))

    event.terminal, event.direction = True, 1
    scale_tol = np.concatenate([0.1e-6 / np.abs(tip), 0.1e-6 * model.omega / np.abs(tip), [1e-6]])
    atol = np.tile(rtol * scale_tol, bsz)
    out = np.zeros((bsz * dim, len(times)))
    regime = np.zeros((bsz, len(times)), bool)
    events = np.zeros(bsz, int)
    y, t, idx = np.zeros(bsz * dim), times[0], 1
    while idx < len(times):
        blocks = np.where((engaged & stiff)[:, None, None], eng, free[None]) if stiff else \
            np.repeat(free[None], bsz, 0)
        jac = block_diag(list(blocks), format="csc")
        implicit = method == "Radau" or bool(np.any(engaged & stiff))
        kw = {"method": "Radau", "jac": lambda t, y, jac=jac: jac} if implicit else \
            {"method": "DOP853"}
        sol = solve_ivp(rhs, (t, times[-1]), y, t_eval=times[idx:], events=event, rtol=rtol,
                        atol=atol, max_step=times[1] - times[0], **kw)
        if sol.status < 0:
            raise RuntimeError(f"solve_ivp failed at t = {t:.6g} s: {sol.message}")
        m = len(sol.t)
        out[:, idx:idx + m], regime[:, idx:idx + m] = sol.y, engaged[:, None]
        idx += m
        if sol.status != 1:
            break
        t, y = float(sol.t_events[0][0]), sol.y_events[0][0].copy()
        r = int(np.argmax(signs(t, y)))
        engaged[r] = not engaged[r]
        events[r] += 1
        if events[r] > len(times):
            raise RuntimeError(f"record {r}: the contact chatters (more events than samples)")
        y[r * dim + dim - 1] = 0.0  # the force state restarts at 0 at touch, is 0 at release
    return out.reshape(bsz, dim, len(times)), regime, events


GAMMA = 2.0 - math.sqrt(2.0)
"""TR-BDF2's inner point: the trapezoidal stage to ``t + γh``, then BDF2 to ``t + h``; with this
γ both stages solve ``y = a + θ f(t, y)`` with the same ``θ = γh/2`` and the method is
L-stable (the wall's ~1 µs force relaxation is damped in one step, not rung)."""
_BDF_NEW, _BDF_OLD = 1 / (GAMMA * (2 - GAMMA)), -(1 - GAMMA) ** 2 / (GAMMA * (2 - GAMMA))
_CODE = {law: i for i, law in enumerate(LAWS)}
(_SCALE, _GAP, _K, _C, _GAIN, _N, _ALPHA, _KM, _KH) = range(9)
"""Slots of a record's parameters in the fixed-step kernel (:func:`_fixed_step`)."""


@njit(cache=True)
def _drive_at(t, drv):
    """E (V) and dE/dt (V/s) of :class:`_Drive` at t; ``drv = [AL, ωL, AH, ωH, lead_s]``."""
    al, wl, ah, wh, lead = drv[0], drv[1], drv[2], drv[3], drv[4]
    e = -al * math.cos(wl * t) + ah * math.sin(wh * t)
    de = al * wl * math.sin(wl * t) + ah * wh * math.cos(wh * t)
    if t >= 0.0:
        return e, de
    x = (t + lead) / lead
    if x <= 0.0:
        return 0.0, 0.0
    r = 0.5 - 0.5 * math.cos(math.pi * x)
    return e * r, de * r + e * 0.5 * math.pi / lead * math.sin(math.pi * x)


@njit(cache=True)
def _root_power(x, c, n, start):
    """δ ≥ 0 with ``δ + c δ^n = x`` (x > 0, c ≥ 0, n ≥ 1) by Newton from ``start`` where it is
    > 0 (a nearby root), else from an upper bound: the left side is convex and increasing, so
    the iterates stay positive and are monotone after the first."""
    d = x if c <= 0.0 else min(x, (x / c) ** (1.0 / n))
    if start > 0.0:
        d = min(d, start)
    for _ in range(100):
        step = (d + c * d**n - x) / (1.0 + c * n * d ** (n - 1.0))
        d -= step
        if abs(step) <= 1e-15 * d:
            break
    return d


@njit(cache=True)
def _closure(law, par, a_r, x, u1, v0, v1, af, theta):
    """The stage's force F (N): the modal tip's overshoot is ``u_m − g = x − u1 F`` and its
    rate ``v0 − v1 F`` (the stage's own compliance u1, v1 > 0), the penetration
    ``δ = u_m − g − a_r F``. Damped linear wall: the force state's stage equation in its
    mass form, ``c a_r F = af + θ (k (u_m − g) + c u_m' − (1 + k a_r) F)``, linear in F;
    the other laws are algebraic, ``F = f(δ, δ')``, solved by Newton (module docstring)."""
    if law == 0:
        k, c = par[_K], par[_C]
        return (af + theta * (k * x + c * v0)) / (c * a_r + theta * (1.0 + k * (a_r + u1)
                                                                  + c * v1))
    if x <= 0.0:
        return 0.0
    if law == 3:
        kh = par[_KH]
        comp = (u1 + a_r + 1.0 / par[_KM]) * kh
        s = min(math.sqrt(x), (x / comp) ** (1.0 / 3.0))  # above the root
        for _ in range(100):
            step = (comp * s**3 + s * s - x) / (3.0 * comp * s * s + 2.0 * s)
            s -= step
            if abs(step) <= 1e-15 * s:
                break
        return kh * s**3
    n, gain = par[_N], par[_GAIN]
    d = _root_power(x, (u1 + a_r) * gain, n, 0.0)
    f = gain * d**n
    if law == 1:
        return f
    for _ in range(100):  # Hunt–Crossley: K (1 + α δ') with δ' on the elastic branch, by
        # fixed point (the damping's share of F is ~α δ' ≈ 1e-4: it contracts at once)
        rate = (v0 - v1 * f) / (1.0 + a_r * n * f / d)
        k = gain * max(1.0 + par[_ALPHA] * rate, 0.0)
        d = _root_power(x, (u1 + a_r) * k, n, d)
        new = k * d**n
        if abs(new - f) <= 1e-13 * new or d == 0.0:
            return new
        f = new
    return f


@njit(cache=True)
def _stage(omega, zeta, tip, cpl, a_r, br, law, par, drv, aq, av, af, theta, t, engaged, q, v):
    """One implicit stage ``y = a + θ f(t, y)`` for ``y = [q, q']`` (and F): per mode,
    ``q' (1 + 2ζΩθ + Ω²θ²) = a_v − θ Ω² a_q + θ φθ E − θ φb F``, ``q = a_q + θ q'``, so the
    modal tip and its rate are affine in the stage's F, closed by the law
    (:func:`_closure`). Writes q, q'; returns F, the overshoot ``u_m − g`` and ``u_m'``."""
    e, de = _drive_at(t, drv)
    u0, u1, v0, v1 = br * e, 0.0, br * de, 0.0
    for i in range(len(omega)):
        w2 = omega[i] * omega[i]
        d = 1.0 + theta * (2.0 * zeta[i] * omega[i] + theta * w2)
        p = (av[i] - theta * (w2 * aq[i] - cpl[i] * e)) / d
        r = theta * tip[i] / d
        v[i], q[i] = p, r
        u0 += tip[i] * (aq[i] + theta * p)
        u1 += theta * tip[i] * r
        v0 += tip[i] * p
        v1 += tip[i] * r
    x = u0 - par[_GAP]
    f = _closure(law, par, a_r, x, u1, v0, v1, af, theta) if engaged else 0.0
    for i in range(len(omega)):
        v[i] -= q[i] * f
        q[i] = aq[i] + theta * v[i]
    return f, x - u1 * f, v0 - v1 * f


@njit(cache=True)
def _trbdf2(omega, zeta, tip, cpl, a_r, br, law, par, drv, t, h, q0, v0, f0, engaged, work,
            q1, v1):
    """One TR-BDF2 step of length h from ``(q0, q0', F0)`` at t (``work`` (4, n) scratch);
    writes ``q1, q1'``, returns ``F1`` and the regime's event function at ``t + h``
    (free: the would-be touch, > 0 past it; engaged: the force or the overshoot, < 0 past
    the release)."""
    n = len(omega)
    aq, av, qg, vg = work[0], work[1], work[2], work[3]
    theta = 0.5 * GAMMA * h
    e, de = _drive_at(t, drv)
    um, ud = br * e - par[_GAP], br * de
    for i in range(n):
        um += tip[i] * q0[i]
        ud += tip[i] * v0[i]
    k, c = par[_K], par[_C]
    af = 0.0
    if engaged and law == 0:
        af = c * a_r * f0 + theta * (k * um + c * ud - (1.0 + k * a_r) * f0)
    for i in range(n):
        acc = (-omega[i] * (omega[i] * q0[i] + 2.0 * zeta[i] * v0[i]) + cpl[i] * e
               - tip[i] * f0)
        aq[i] = q0[i] + theta * v0[i]
        av[i] = v0[i] + theta * acc
    fg = _stage(omega, zeta, tip, cpl, a_r, br, law, par, drv, aq, av, af, theta,
                t + GAMMA * h, engaged, qg, vg)[0]
    for i in range(n):
        aq[i] = _BDF_NEW * qg[i] + _BDF_OLD * q0[i]
        av[i] = _BDF_NEW * vg[i] + _BDF_OLD * v0[i]
    af = c * a_r * (_BDF_NEW * fg + _BDF_OLD * f0)
    f1, over, rate = _stage(omega, zeta, tip, cpl, a_r, br, law, par, drv, aq, av, af, theta,
                            t + h, engaged, q1, v1)
    if law == 0:
        return f1, f1 if engaged else min(over, k * over + c * rate)
    return f1, over


@njit(cache=True)
def _fixed_step(omega, zeta, tip, coupling, a_r, beta_r, law, pars, drv, t0, dt, substeps,
                n_t, state, engaged_out, events):
    """Every record (``pars`` (B, 9), :data:`_SCALE`...) from rest at t0 by TR-BDF2 at
    ``dt/substeps``, touch and release located inside the step (module docstring); writes
    the states ``[q, q', F]`` at the samples ``state`` (B, 2n+1, n_t), the regime there
    ``engaged_out`` (B, n_t) and the events per record ``events`` (B,) (−1: it chatters).

    Each step's trial (one call of :func:`_trbdf2`, of a fraction of what is left of the
    step) goes by phases: the whole step; where it crosses an event just after another
    (``fresh``: the start is on the event), halving the fraction until one ends inside (none
    above 1e-12: the contact is undone); Illinois on the fraction between a trial inside
    and one past; the step to the located crossing, where the regime switches."""
    n = len(omega)
    h = dt / substeps
    work = np.zeros((4, n))
    q, v, qn, vn = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    cpl = np.zeros(n)
    whole, halve, locate, cut = 0, 1, 2, 3
    for b in range(pars.shape[0]):
        par = pars[b]
        for i in range(n):
            cpl[i] = coupling[i] * par[_SCALE]
        br = beta_r * par[_SCALE]
        q[:] = 0.0
        v[:] = 0.0
        f = 0.0
        engaged = par[_GAP] < 0.0  # a wall the tip rests past
        state[b, :, 0] = 0.0
        engaged_out[b, 0] = engaged
        count, fresh, g_prev = 0, False, -1.0
        for j in range((n_t - 1) * substeps):
            t, t_end = t0 + j * h, t0 + (j + 1) * h
            phase, frac, span = whole, 1.0, t_end - t
            lo, g_lo, hi, g_hi, side = 0.0, g_prev, 1.0, 0.0, 0
            while True:
                f_new, g = _trbdf2(omega, zeta, tip, cpl, a_r, br, law, par, drv, t,
                                   frac * span, q, v, f, engaged, work, qn, vn)
                g *= -1.0 if engaged else 1.0  # the event function, oriented: > 0 past
                if phase == cut or (phase == whole and g <= 0.0):
                    q[:] = qn
                    v[:] = vn
                    t += frac * span
                    if phase == whole:
                        f, g_prev, fresh = f_new, g, False
                        break
                    phase = halve  # past the cut: switch, then take what is left
                elif phase == whole:
                    hi, g_hi = 1.0, g
                    if fresh:
                        phase, frac = halve, 0.5
                        continue
                    phase = locate
                elif phase == halve:
                    if g < 0.0:
                        lo, g_lo, phase = frac, g, locate
                    else:
                        hi, g_hi, frac = frac, g, 0.5 * frac
                        if frac > 1e-12:
                            continue
                else:
                    if g >= 0.0:
                        hi, g_hi = frac, g
                        if side == -1:
                            g_lo *= 0.5
                        side = -1
                    else:
                        lo, g_lo = frac, g
                        if side == 1:
                            g_hi *= 0.5
                        side = 1
                    if hi - lo <= 1e-13 or g == 0.0:
                        phase, frac = cut, hi
                        continue
                if phase == locate:
                    frac = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
                    if not lo < frac < hi:
                        frac = 0.5 * (lo + hi)
                    continue
                # a located crossing (or, from halve, none inside: undone where it starts)
                f = 0.0  # the force is 0 at every touch and release
                engaged = not engaged
                fresh = True
                count += 1
                if count > 4 * n_t:
                    events[b] = -1
                    return
                if t_end - t <= 1e-12 * h:
                    break
                phase, frac, span = whole, 1.0, t_end - t
                lo, g_lo, hi, side = 0.0, 0.0, 1.0, 0
            if (j + 1) % substeps == 0:
                s = (j + 1) // substeps
                state[b, :n, s] = q
                state[b, n:2 * n, s] = v
                state[b, 2 * n, s] = f
                engaged_out[b, s] = engaged
        events[b] = count


def _simulate_fixed(model: ModalModel, scale: np.ndarray, law: ContactLaw, gap: np.ndarray,
                    drive: _Drive, times: np.ndarray, substeps: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """B records from rest by TR-BDF2 at ``dt/substeps`` (:func:`_fixed_step`), in the format
    of :func:`_simulate_batch`: states ``(B, 2n+1, n_t)``, regimes ``(B, n_t)``, events
    ``(B,)``."""
    n, bsz = len(model.omega), len(gap)
    pars = np.zeros((bsz, 9))
    pars[:, _SCALE], pars[:, _GAP] = scale, gap
    pars[:, _K], pars[:, _C] = law.stiffness, law.damping
    pars[:, _GAIN], pars[:, _N], pars[:, _ALPHA] = law.gain, law.exponent, law.alpha_s_per_m
    pars[:, _KM], pars[:, _KH] = law.hertz()
    drv = np.array([drive.al, drive.wl, drive.ah, drive.wh, max(drive.lead, 1e-300)])
    state = np.zeros((bsz, 2 * n + 1, len(times)))
    engaged = np.zeros((bsz, len(times)), bool)
    events = np.zeros(bsz, np.int64)
    _fixed_step(model.omega, model.zeta, model.tip, model.coupling, model.a_r, model.beta_r,
                _CODE[law.law], pars, drv, float(times[0]), float(times[1] - times[0]),
                int(substeps), len(times), state, engaged, events)
    if np.any(events < 0):
        raise RuntimeError(f"records {np.flatnonzero(events < 0).tolist()}: the contact "
                           "chatters (more events than four per sample)")
    return state, engaged, events


def _current(model: ModalModel, scale: np.ndarray, law: ContactLaw, gap: np.ndarray,
             drive: _Drive, times: np.ndarray, state: np.ndarray, engaged: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The current I (A), tip displacement u (m) and force F (N) at ``times`` from the states
    ``(B, 2n+1, n_t)``, each ``(B, n_t)``."""
    n = len(model.omega)
    el, dl, eh, dh = drive.tones(times)
    e, de = el + eh, dl + dh
    br, col = model.beta_r * scale[:, None], (slice(None), None)
    over = np.einsum("i,bit->bt", model.tip, state[:, :n]) + br * e - gap[col]
    rate = np.einsum("i,bit->bt", model.tip, state[:, n:2 * n]) + br * de
    if law.stiff_state:
        force = state[:, -1]
        k, c = law.stiffness[col], law.damping[col]
        force_rate = (k * over + c * rate - (1 + k * model.a_r) * force) / (c * model.a_r)
    else:
        force, force_rate = law.force(over, rate, model.a_r)
    force, force_rate = np.where(engaged, force, 0.0), np.where(engaged, force_rate, 0.0)
    loss = model.capacitance * model.tan_delta * (drive.wl * el + drive.wh * eh)
    motional = np.einsum("i,bit->bt", model.coupling, state[:, n:2 * n]) * scale[col]
    cap = model.capacitance + model.delta_r * scale[col] ** 2
    i = motional - br * force_rate + cap * de + loss
    return i, over + gap[col] - model.a_r * force, force


def contact_law(law: str, stiffness, damping, law_params: dict | None, n: int) -> ContactLaw:
    """The :class:`ContactLaw` of ``n`` records from per-record (or scalar) parameters."""
    if law not in LAWS:
        raise ValueError(f"law must be one of {LAWS}, got {law!r}")
    params = dict(LAW_DEFAULTS[law])
    extra = set(law_params or {}) - set(params)
    if extra:
        raise ValueError(f"law_params: {sorted(extra)} not parameters of the {law!r} law "
                         f"(it takes {sorted(params) or 'none'})")
    params |= law_params or {}
    cols = {"stiffness": check_range("stiffness", np.broadcast_to(stiffness, (n,)), 0.0, np.inf,
                                     unit="N/m", low_open=True, high_open=True),
            "damping": check_range("damping", np.broadcast_to(damping, (n,)), 0.0, 1.0,
                                   unit="N·s/m")}
    if law == "linear" and np.any(cols["damping"] > 0) and np.any(cols["damping"] == 0):
        raise ValueError("damping: a batch of the linear law is all damped or all undamped")
    for name in LAW_RANGES:
        value = params.get(name, _UNUSED[name])
        lo, hi, unit = LAW_RANGES[name]
        cols[name] = check_range(f"law_params.{name}", np.broadcast_to(value, (n,)), lo, hi,
                                 unit=unit)
    return ContactLaw(law, **{f: np.array(v) for f, v in cols.items()})


def simulate_onset(scene, gaps, stiffness, damping, coupling, *, law: str = "linear",
                   law_params: dict | None = None, rng: np.random.Generator | None = None,
                   method: str = "trbdf2", substeps: int = 16, rtol: float = 1e-9,
                   n_modes: int | None = None, batch: int = 32, detail: bool = False
                   ) -> dict[str, np.ndarray]:
    """Records of ``scene`` (an :class:`~wtml.scenes.onset.OnsetScene`) from this simulator,
    in the format of ``OnsetScene.simulate``.

    Args:
        gaps: the wall's g per record, m, ``(n,)`` (NaN: no wall, free whisking).
        stiffness: k (linear) or k_ref (the other laws), N/m, ``(n,)`` or scalar.
        damping: c of the linear law, N·s/m, ``(n,)`` or scalar (the other laws ignore it).
        coupling: each record's device, its piezo coupling scale, ``(n,)`` or scalar.
        law: one of :data:`LAWS`; law_params: its parameters (:data:`LAW_DEFAULTS`), each a
            scalar or ``(n,)``.
        rng: draws the acquisition's noise; None: no noise (the ADC still applies).
        method: ``"trbdf2"`` (default: the fixed-step integrator, :func:`_fixed_step`),
            or solve_ivp's ``"DOP853"`` (Radau wherever a force is a stiff state) or
            ``"Radau"`` throughout (:func:`_simulate_batch`, ~100 times slower: the
            cross-check).
        substeps: steps per sample interval of the fixed-step integrator (1 to 256).
        rtol: solve_ivp's relative tolerance (module docstring for atol).
        n_modes: modes kept (default the scene's).
        batch: records integrated side by side by solve_ivp (:func:`_simulate_batch`).
        detail: also return ``current`` (A, before noise and ADC), ``u`` (m) and ``force`` (N),
            float64 ``(n, n_samples)``, and ``events`` ``(n,)``.

    Returns:
        ``e``, ``i`` float32 ``(n, n_samples)`` (V, A); ``gap``, ``onset``, ``detachment``
        (s, ``(n, max_contacts)``), ``stiffness``, ``damping``, ``coupling``; the device's
        calibration ``t_probe`` (its T at the probe, ``(n, 2, 2)``) and ``hue0`` (m/V, ``(n,)``)
        from this simulator's own modal model.
    """
    gaps = np.atleast_1d(np.asarray(gaps, dtype=float))
    n = len(gaps)
    law_ = contact_law(law, stiffness, damping, law_params, n)
    scale = check_range("coupling", np.broadcast_to(np.asarray(coupling, float), (n,)), 0.0,
                        np.inf, low_open=True, high_open=True)
    check_range("rtol", rtol, 1e-13, 1e-3)
    check_range("batch", batch, 1, 10**4)
    check_range("substeps", substeps, 1, 256)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    model = ModalModel.from_beam(scene.beam(), n_modes or scene.n_modes)
    if not model.a_r > 0:
        raise ValueError(f"n_modes: {len(model.omega)} leaves no residual compliance "
                         f"(a_r = {model.a_r:.3g} m/N); keep fewer modes")
    drive = _Drive(scene)
    a, rate = scene.acquisition, scene.acquisition.sample_rate_hz
    n_lead = int(round(scene.drive.lead_s * rate))
    times = np.arange(-n_lead, scene.n_samples) / rate
    cur = np.empty((n, len(times)))
    u, force = np.empty_like(cur), np.empty_like(cur)
    touching = np.empty((n, len(times)), bool)
    events = np.zeros(n, int)
    g = np.where(np.isnan(gaps), 1.0, gaps)  # no wall: one beyond any reach
    size = n if method == "trbdf2" else batch
    for start in range(0, n, size):
        sl = slice(start, min(n, start + size))
        part = ContactLaw(law, *(getattr(law_, f.name)[sl]
                                 for f in dataclasses.fields(ContactLaw)[1:]))
        if method == "trbdf2":
            state, touching[sl], events[sl] = _simulate_fixed(model, scale[sl], part, g[sl],
                                                              drive, times, substeps)
        else:
            state, touching[sl], events[sl] = _simulate_batch(model, scale[sl], part, g[sl],
                                                              drive, times, rtol, method)
        cur[sl], u[sl], force[sl] = _current(model, scale[sl], part, g[sl], drive, times, state,
                                             touching[sl])
    cur, u, force, touching = (x[:, n_lead:] for x in (cur, u, force, touching))
    e = scene.drive_voltage()[0]
    if rng is None:
        e_rec, i_rec = np.broadcast_to(e, cur.shape), cur
    else:
        e_rec = e[None] + a.e_noise_v * rng.standard_normal(cur.shape)
        i_rec = cur + a.i_noise_a * rng.standard_normal(cur.shape)
    onset, detach = scene.contacts(touching)
    out = {"e": quantize(e_rec, a.adc_bits, a.e_full_scale_v).astype(np.float32),
           "i": quantize(i_rec, a.adc_bits, a.i_full_scale_a).astype(np.float32),
           "gap": gaps, "onset": onset, "detachment": detach,
           "stiffness": law_.stiffness, "damping": law_.damping, "coupling": np.array(scale)}
    # the user's calibration of this simulator's device (its own modal model): T at the probe
    # and HUE(0), as OnsetScene.simulate gives them
    t_probe = model.transduction_matrix(np.array([2 * np.pi * scene.drive.probe_hz]))[0]
    out |= {"t_probe": np.repeat(t_probe[None], n, 0),
            "hue0": np.full(n, model.static_tip_displacement_per_volt())}
    if detail:
        out |= {"current": cur, "u": u, "force": force, "events": events}
    return out


def simulate_like(scene, records: dict, **kwargs) -> dict[str, np.ndarray]:
    """This simulator's records of the same walls and devices as ``records`` (what
    ``OnsetScene.simulate`` returns: ``gap``, ``stiffness``, ``damping``, ``coupling`` and the
    law's labels ``law`` (codes in the order of :data:`LAWS`), ``law_n``, ``law_alpha``,
    ``law_delta_ref``, ``law_mount_fraction``), each law's records in one call of
    :func:`simulate_onset` (``kwargs`` passed on: ``rng``, ``method``, ``detail``...).
    Returns its outputs in the order of ``records``."""
    codes = np.asarray(records.get("law", np.zeros(len(records["gap"]), int)))
    params = {"power": {"exponent": "law_n", "reference_m": "law_delta_ref"},
              "hunt_crossley": {"exponent": "law_n", "reference_m": "law_delta_ref",
                                "alpha_s_per_m": "law_alpha"},
              "mount_hertz": {"reference_m": "law_delta_ref",
                              "mount_fraction": "law_mount_fraction"}}
    out: dict[str, np.ndarray] = {}
    for code in np.unique(codes):
        rows = np.flatnonzero(codes == code)
        law = LAWS[int(code)]
        part = simulate_onset(scene, records["gap"][rows], records["stiffness"][rows],
                              records["damping"][rows], records["coupling"][rows], law=law,
                              law_params={p: records[key][rows]
                                          for p, key in params.get(law, {}).items()},
                              **kwargs)
        for key, value in part.items():
            if key not in out:
                out[key] = np.zeros((len(codes),) + value.shape[1:], value.dtype)
            out[key][rows] = value
    return out
