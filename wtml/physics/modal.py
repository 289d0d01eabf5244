"""The transducer in the time domain: a modal state-space model of a beam (physics.md §9).

Mass-normalised modes of the short-circuited beam with a free tip, the n lowest kept, and the
static correction of the truncated ones (mode-acceleration method)::

    q'' + 2ζΩ q' + Ω² q = φθ E - φb F
    u = φb·q - a_r F + β_r E,      Q = φθ·q - β_r F + (Cp + δ_r) E,      I = Q' + I_loss

with ``φb = bᵀΦ`` (the modes at the tip), ``φθ = ΘᵀΦ`` (their coupling) and the residuals
``a_r, β_r, δ_r`` of ``K⁻¹ - ΦΩ⁻²Φᵀ`` (summed over the truncated modes), so that HUE(0) does
not depend on n (it is the beam's to the eigensolver's ~1e-8). Damping: modal
viscous ``ζ_i = η_i/2`` from each mode's loss factor (the beam's complex modulus has no causal
time-domain form). Dielectric loss: a constant tanδ, ``Cp (1 - j tanδ)`` at every ω in T,
and in the time domain a loss current ``ω Cp tanδ E`` in phase with each tone of the drive
(:meth:`ModalTransducer.loss_current`): a conductance that grows with frequency, not one
conductance exact at one frequency only (physics.md §9). It is linear in E and depends on no
state, so it is added to the current after stepping, whatever the stepper. The two damping
models differ off resonance (1.3 % in the micro preset's free-tip Ze at 420 Hz), so a
time-domain scene's true T is :meth:`ModalTransducer.transduction_matrix`.

Loads at the tip (:class:`TipLoad`) are piecewise linear: each is a linear force law
``F = k (u - g) + c u'`` while engaged and 0 while not, with a rule for switching. Between
switches the system is linear and time-invariant and is stepped exactly, the drive held first-order
(piecewise linear E: the matrix exponential of the system augmented with E, E' and g). Each
regime's exact map is diagonalised once, so a step costs O(n) per record, not O(n²); a switch
changes basis through the physical state. Records are stepped side by side in blocks, one block
per core. The force of an engaged load is part of the linear system, never fed back explicitly
(explicit feedback is unstable for stiff walls, §9). With a residual compliance ``a_r > 0`` and
a damped load, ``F`` is a state: ``c a_r F' + (1 + k a_r) F = k (u_m - g) + c u_m'`` where
``u_m = φb·q + β_r E``; otherwise it is algebraic.

How many modes: :func:`truncation_errors` measures a truncation against the model with every
mode kept, as the largest relative error of Ze with the tip free and with it clamped (the two
limits of any tip load's Ze) over a band; :func:`fewest_modes` picks the fewest modes within a
tolerance there. A scene's ``n_modes: auto`` uses it over the scene's band with its
``modes_tolerance`` (``wtml.scenes.modes``, configs/README.md).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.linalg import eigh, expm

from wtml.cores import available_cores
from wtml.physics.beam import BeamTransducer
from wtml.physics.contact import CONTACT_OUTPUTS, simulate_contact
from wtml.physics.friction import simulate_friction
from wtml.physics.stepping import eigenbasis, record_blocks
from wtml.physics.structure import Structure
from wtml.physics.validation import check_omega, check_range

OUTPUTS = ("u", "v", "force", "i")
"""What :meth:`ModalTransducer.simulate` records at every step: tip displacement (m), tip
velocity (m/s), the force the transducer applies to the load (N) and the current (A)."""


@dataclass(frozen=True)
class ModalTransducer(Structure):
    """A piezo-coupled structure reduced to ``n`` modes with static correction.

    Attributes:
        omega_n: natural angular frequencies Ω, rad/s, shape ``(n,)``.
        zeta: modal damping ratios, shape ``(n,)``.
        tip: φb, the mass-normalised modes' tip displacement, m/√kg, shape ``(n,)``.
        coupling: φθ, their electromechanical coupling, N/(V·√kg), shape ``(n,)``.
        residual: ``(a_r m/N, β_r m/V, δ_r F)`` of the truncated modes.
        capacitance: clamped capacitance Cp (real), F.
        loss_tangent: the dielectric's tanδ (constant in ω): ``Cp (1 - j tanδ)``.
        tip_slope: the kept modes' tip slope θ = ∂w/∂x at the tip, rad/√kg per unit modal
            coordinate, shape ``(n,)``, or None (a model not made from a beam): what a
            tangential force at the tip's surface acts through (a wall's friction,
            :mod:`wtml.physics.contact`).
    """

    omega_n: np.ndarray
    zeta: np.ndarray
    tip: np.ndarray
    coupling: np.ndarray
    residual: tuple[float, float, float] = (0.0, 0.0, 0.0)
    capacitance: float = 0.0
    loss_tangent: float = 0.0
    tip_slope: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.shape(self.omega_n)
        for name in ("zeta", "tip", "coupling") + (("tip_slope",) if self.tip_slope is not None
                                                   else ()):
            if np.shape(getattr(self, name)) != n:
                raise ValueError(f"{name} must have the shape of omega_n {n}, "
                                 f"got {np.shape(getattr(self, name))}")
        check_range("omega_n", self.omega_n, 0.0, np.inf, unit="rad/s", low_open=True,
                    high_open=True)
        check_range("zeta", self.zeta, 0.0, 1.0)
        check_range("residual a_r", self.residual[0], 0.0, np.inf, unit="m/N", high_open=True)
        check_range("capacitance", self.capacitance, 0.0, np.inf, unit="F", high_open=True)
        check_range("loss_tangent", self.loss_tangent, 0.0, 1.0)

    @property
    def n_modes(self) -> int:
        return len(self.omega_n)

    @classmethod
    def from_beam(cls, beam: BeamTransducer, n_modes: int = 3) -> ModalTransducer:
        """The ``n_modes`` lowest modes of ``beam`` with static correction, and the beam's
        clamped capacitance ``Cp (1 - j tanδ)``.

        Args:
            beam: the full model.
            n_modes: modes kept, 1 to the beam's number of DOFs.
        """
        k, m, theta = beam.matrices()
        n_dof = len(theta)
        check_range("n_modes", n_modes, 1, n_dof)
        w2, phi = eigh(k.real, m)  # every mode, ΦᵀMΦ = 1
        at_tip, coupled = phi[-2], theta @ phi
        kept, cut = slice(0, int(n_modes)), slice(int(n_modes), None)
        # K⁻¹ - ΦΩ⁻²Φᵀ summed over the truncated modes themselves: the difference of the two
        # matrices loses ~1e-9 m/N to K's conditioning and can turn a_r negative.
        residual = tuple(float(np.sum(x[cut] * y[cut] / w2[cut])) for x, y in
                         ((at_tip, at_tip), (at_tip, coupled), (coupled, coupled)))
        w2, phi = w2[kept], phi[:, kept]
        omega = np.sqrt(w2)
        eta = np.einsum("ji,jk,ki->i", phi, k.imag, phi) / w2
        cp = complex(beam.capacitance)
        return cls(omega, eta / 2, at_tip[kept], coupled[kept], residual, cp.real,
                   -cp.imag / cp.real, phi[-1])

    def with_coupling(self, scale: float) -> ModalTransducer:
        """The same structure with its piezo coupling scaled by ``scale`` (a device whose
        HUE(0) and T differ from the calibrated one by about ``scale - 1``)."""
        a_r, b_r, d_r = self.residual
        return ModalTransducer(self.omega_n, self.zeta, self.tip, self.coupling * scale,
                               (a_r, b_r * scale, d_r * scale**2), self.capacitance,
                               self.loss_tangent, self.tip_slope)

    def _forms(self, omega: np.ndarray):
        w = omega[..., None]
        h = 1.0 / (self.omega_n**2 - w**2 + 2j * self.zeta * self.omega_n * w)
        a_r, b_r, d_r = self.residual
        a = h @ self.tip**2 + a_r
        beta = h @ (self.tip * self.coupling) + b_r
        delta = h @ self.coupling**2 + d_r + self.capacitance * (1 - 1j * self.loss_tangent)
        return a, beta, delta

    def transduction_matrix(self, omega) -> np.ndarray:
        """T(ω) of the modal model with a free tip, shape ``omega.shape + (2, 2)``, det T = 1."""
        omega = check_omega(omega)
        return BeamTransducer._t_from_forms(omega, *self._forms(omega))

    def static_tip_displacement_per_volt(self) -> float:
        """HUE(0) = ``Σ φb φθ / Ω² + β_r``, m/V: the beam's (to ~1e-8), whatever n."""
        return float(np.sum(self.tip * self.coupling / self.omega_n**2) + self.residual[1])

    def step_matrices(self, dt: float, stiffness, damping, coupling_scale=1.0,
                      force_input: bool = False):
        """The exact one-step map and the outputs of the system with an engaged linear load
        ``F = k (u - g) + c u'`` (``k = c = 0``: a free tip), for a batch of B samples.

        The state is ``x = [q (n), q' (n), F]``; the augmented vector is
        ``z = [x, E_k, Ė_k, g, Ė_out]`` (``Ė_k`` the drive's slope over the step, ``Ė_out`` its
        rate at the sample, for the outputs). Returns ``M`` of shape ``(B, 2n+1+4, 2n+5)``:
        its first ``2n+1`` rows give ``x_{k+1}``, the last four give ``(u, u', F, i)`` at k
        (``i`` without the dielectric loss current, which :meth:`simulate` adds).

        Args:
            dt: the step, s.
            stiffness, damping: k (N/m) and c (N·s/m) of the engaged load, shape ``(B,)``.
            coupling_scale: each sample's device as :meth:`with_coupling`, ``(B,)`` or scalar.
            force_input: with a free tip only: the slot of g carries instead a force F applied
                by the tip to the load and held over the step (a smooth load evaluated once per
                step, :mod:`wtml.physics.friction`); it enters u through the residual
                compliance and is the force output. Its rate is not modelled (the residual's
                ``-a_r F'`` in u' and ``-β_r F'`` in i are left out).
        """
        k = np.atleast_1d(np.asarray(stiffness, dtype=float))
        bsz = len(k)
        c = np.broadcast_to(np.asarray(damping, dtype=float), k.shape)
        s = np.broadcast_to(np.asarray(coupling_scale, dtype=float), k.shape)[:, None]
        n = self.n_modes
        ns, nz = 2 * n + 1, 2 * n + 5
        iq, iv, i_f, i_e, i_de, i_g, i_do = (slice(0, n), slice(n, 2 * n), 2 * n, 2 * n + 1,
                                             2 * n + 2, 2 * n + 3, 2 * n + 4)
        a_r, b_r, d_r = self.residual
        b_r = b_r * s[:, 0]
        # u_m = φb·q + β_r E and u_m' = φb·q' + β_r Ė as forms over z (Ė: stepping slope)
        um = np.zeros((bsz, nz))
        um[:, iq], um[:, i_e] = self.tip, b_r
        dum = np.zeros((bsz, nz))
        dum[:, iv], dum[:, i_de] = self.tip, b_r
        gap = np.zeros(nz)
        gap[i_g] = 1.0
        drive = k[:, None] * (um - gap) + c[:, None] * dum  # k (u_m - g) + c u_m', (B, nz)
        stateful = (c * a_r > 0)[:, None]
        tau_c = np.where(stateful[:, 0], c * a_r, 1.0)[:, None]
        soft = (1 + k * a_r)[:, None]
        e_f = np.zeros(nz)
        e_f[i_f] = 1.0
        force = np.where(stateful, e_f, drive / soft)  # F as a form over z
        dforce = np.where(stateful, (drive - soft * e_f) / tau_c,
                          k[:, None] * dum / soft)  # F' (algebraic case: c = 0 or a_r = 0)
        engaged = ((k > 0) | (c > 0))[:, None]
        force, dforce = np.where(engaged, force, 0.0), np.where(engaged, dforce, 0.0)

        a = np.zeros((bsz, nz, nz))
        a[:, iq, iv] = np.eye(n)
        a[:, iv, iq] = -np.diag(self.omega_n**2)
        a[:, iv, iv] = -np.diag(2 * self.zeta * self.omega_n)
        a[:, iv, i_e] = self.coupling * s
        a[:, iv, :] -= self.tip[None, :, None] * force[:, None, :]
        a[:, i_f, :] = np.where(stateful, dforce, 0.0)
        a[:, i_e, i_de] = 1.0
        if force_input:
            if np.any(engaged):
                raise ValueError("force_input: only with a free tip (stiffness = damping = 0)")
            a[:, iv, i_g] = -self.tip
            force = np.broadcast_to(gap, (bsz, nz))
        step = expm(a * dt)[:, :ns, :]
        step[:, :, i_do] = 0.0

        out = np.zeros((bsz, 4, nz))
        out[:, 0] = um - a_r * force
        out[:, 1] = dum - a_r * dforce
        out[:, 2] = force
        cur = np.zeros((bsz, nz))
        cur[:, iv] = self.coupling * s
        cur[:, i_de] = self.capacitance + d_r * s[:, 0] ** 2
        out[:, 3] = cur - b_r[:, None] * dforce
        # at the sample the outputs use the drive's rate there, not the step's slope
        out[..., i_do], out[..., i_de] = out[..., i_de], 0.0
        return np.concatenate([step, out], axis=1)

    def loss_current(self, drive, tones) -> np.ndarray:
        """The dielectric loss current (A) of constant tanδ, the part of ``jω Cp (1 - j tanδ) E``
        in phase with E: ``Σ_k ω_k Cp tanδ E_k(t)`` for a drive that is a sum of tones E_k.

        Args:
            drive: E in V at the sample instants, shape ``(..., n_steps)``.
            tones: the drive as a sum of tones, each ``(omega, samples)``: ω in rad/s (scalar,
                or per record ``(B,)``) and that tone's E in V (ramps and amplitude errors
                included), broadcastable to ``drive``; their sum must be the drive.

        Returns:
            shape of ``drive`` (tones broadcast against it), A.
        """
        e = np.asarray(drive, dtype=float)
        total, loss = np.zeros(e.shape), np.zeros(e.shape)
        for k, (omega, samples) in enumerate(tones):
            w = np.asarray(omega, dtype=float)
            check_range(f"tones[{k}] omega", w, 0.0, np.inf, unit="rad/s", high_open=True)
            w = w[..., None] if w.ndim else w  # per record: (B, 1)
            x = np.asarray(samples, dtype=float)
            total, loss = total + x, loss + w * x
        off = float(np.max(np.abs(total - e), initial=0.0))
        if not off <= 1e-9 * float(np.max(np.abs(e), initial=0.0)):
            raise ValueError(f"tones: their sum differs from the drive by up to {off:.3g} V; "
                             "they must add up to it")
        return self.capacitance * self.loss_tangent * loss

    def simulate(self, drive, dt: float, load: TipLoad, *, drive_rate=None, coupling_scale=1.0,
                 record: tuple[str, ...] = OUTPUTS, dtype=np.float32,
                 threads: int | None = None, tones=None) -> dict[str, np.ndarray]:
        """Step the transducer from rest under the voltage ``drive`` with ``load`` at the tip.

        Args:
            drive: E in V at the sample instants ``k dt``, shape ``(n_steps,)`` (shared by the
                batch) or ``(B, n_steps)``.
            dt: the step, s (> 0).
            load: a :class:`TipLoad` with batch size B (its parameters' length), a smooth
                load (:class:`~wtml.physics.friction.Friction`) evaluated once per step, or a
                contact law (:class:`~wtml.physics.contact.ContactWall`) solved implicitly.
            drive_rate: dE/dt in V/s at the samples, same shape as ``drive`` (default: central
                differences); used for the outputs (the capacitive current), not the stepping.
            coupling_scale: each sample's device, ``(B,)`` or scalar (:meth:`with_coupling`).
            record: which of :data:`OUTPUTS` to return (with a contact law also those of
                :data:`~wtml.physics.contact.CONTACT_OUTPUTS`: the wall's friction).
            dtype: of the returned arrays.
            threads: records are stepped in blocks on this many threads (default: every core
                this process may use); the answer does not depend on it.
            tones: the drive as a sum of known tones ``[(omega, samples), ...]`` (see
                :meth:`loss_current`), for the dielectric loss current; required to record
                ``i`` from a lossy model (``loss_tangent > 0``), which has no one conductance.

        Returns:
            each recorded output, shape ``(B, n_steps)``, and ``contact`` (bool, same shape):
            whether the load was engaged at each sample (a contact law: F > 0).
        """
        check_range("dt", dt, 0.0, np.inf, unit="s", low_open=True, high_open=True)
        if threads is not None:
            check_range("threads", threads, 1, 1024)
        implicit = getattr(load, "implicit", False)
        allowed = OUTPUTS + (CONTACT_OUTPUTS if implicit else ())
        unknown = set(record) - set(allowed)
        if unknown:
            raise ValueError(f"record: unknown outputs {sorted(unknown)}; choose from {allowed}")
        bsz = load.batch
        e = np.atleast_2d(np.asarray(drive, dtype=float))  # (1 or B, n_steps)
        if e.ndim != 2 or e.shape[0] not in (1, bsz):
            raise ValueError(f"drive: shape (n_steps,) or ({bsz}, n_steps) for the load's "
                             f"{bsz} samples, got {np.shape(drive)}")
        n_steps = e.shape[1]
        if n_steps < 2:
            raise ValueError("drive needs at least 2 samples")
        if not np.all(np.isfinite(e)):
            raise ValueError("drive must be finite")
        if drive_rate is None:
            de_out = np.gradient(e, dt, axis=1)
        else:
            de_out = np.broadcast_to(np.asarray(drive_rate, dtype=float), e.shape)
        de_step = np.diff(e, axis=1, append=e[:, -1:]) / dt
        cols = np.array([allowed.index(r) for r in record])
        loss = None
        if "i" in record and self.loss_tangent > 0:  # checked before stepping
            if tones is None:
                raise ValueError("tones: the drive's tones [(omega, samples), ...] are needed "
                                 "for the dielectric loss current (ω Cp tanδ E at each tone) "
                                 "when recording i of a lossy model")
            loss = self.loss_current(e, tones)
        if implicit:  # a contact law (and its friction): solved at every step
            values, contact = simulate_contact(self, e, de_step, de_out, dt, load,
                                               coupling_scale, cols, dtype, threads)
            return _with_loss({**dict(zip(record, values, strict=True)), "contact": contact},
                              loss)
        if getattr(load, "smooth", False):  # friction: evaluated once per step
            values = simulate_friction(self, e, de_step, de_out, dt, load, coupling_scale, cols,
                                       dtype, threads)
            out = {**dict(zip(record, values, strict=True)),
                   "contact": np.ones((bsz, n_steps), bool)}
            return _with_loss(out, loss)
        free = eigenbasis(self.step_matrices(dt, np.zeros(bsz), np.zeros(bsz), coupling_scale))
        engaged = eigenbasis(self.step_matrices(dt, load.stiffness, load.damping,
                                                 coupling_scale))
        maps = _regimes(free, engaged, load.offset)
        values = np.empty((len(record), bsz, n_steps), dtype)
        contact = np.empty((bsz, n_steps), bool)
        blocks = record_blocks(bsz, threads)
        engaged0 = load.initial_state()

        def step(b: slice) -> None:
            own = b if len(e) > 1 else slice(0, 1)
            _step_block(*(np.ascontiguousarray(a[..., b]) for a in maps),
                        *(np.ascontiguousarray(a[own]) for a in (e, de_step, de_out)),
                        engaged0[b], load.unilateral, load.offset[b],
                        load.stiffness[b], load.damping[b], cols, values[:, b], contact[b])

        with ThreadPoolExecutor(min(len(blocks), threads or available_cores())) as pool:
            list(pool.map(step, blocks))
        out = dict(zip(record, values, strict=True))
        out["contact"] = contact
        return _with_loss(out, loss)


def _with_loss(out: dict[str, np.ndarray], loss: np.ndarray | None) -> dict[str, np.ndarray]:
    """``out`` of a stepper with the dielectric loss current ``loss`` (A, broadcast to the
    records) added to its current (:meth:`ModalTransducer.loss_current`), in place: the sum is
    formed in float64 and rounded to the records' dtype, as ``(i + loss).astype(dtype)`` would,
    without a second copy of the records."""
    if loss is not None:
        np.add(out["i"], loss, out=out["i"], casting="same_kind")
    return out


class TipLoad(ABC):
    """A piecewise-linear load at the tip, for a batch of B samples: while engaged it pushes
    back with ``F = k (u - g) + c u'``; while not, ``F = 0``.

    Attributes (arrays of shape ``(B,)``): ``stiffness`` k (N/m), ``damping`` c (N·s/m),
    ``offset`` g (m); and ``unilateral``: whether it switches, by the one rule the stepper
    knows (:func:`_step_block`): a free tip touches when ``u > g`` while the load would
    push (``k (u - g) + c u' > 0``), an engaged one leaves when its force turns tensile.
    A load that is not unilateral stays as :meth:`initial_state` says.
    """

    stiffness: np.ndarray
    damping: np.ndarray
    offset: np.ndarray
    unilateral: bool = False

    @property
    def batch(self) -> int:
        return len(self.stiffness)

    @abstractmethod
    def initial_state(self) -> np.ndarray:
        """Engaged at rest, bool ``(B,)``."""


def _batch(name: str, value, unit: str, size: int | None = None, positive: bool = False):
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if size is not None:
        arr = np.broadcast_to(arr, (size,)).copy()
    check_range(name, arr, 0.0, np.inf, unit=unit, high_open=True, low_open=positive)
    return arr


class LinearTipLoad(TipLoad):
    """A spring and damper at the tip, always engaged: ``Zm = c + k/(jω)``."""

    def __init__(self, stiffness, damping) -> None:
        self.stiffness = _batch("stiffness", stiffness, "N/m")
        self.damping = _batch("damping", damping, "N·s/m", len(self.stiffness))
        self.offset = np.zeros(len(self.stiffness))

    def impedance(self, omega) -> np.ndarray:
        """``Zm = c + k/(jω)`` in N·s/m, shape ``(B,) + omega.shape``."""
        w = check_omega(omega)
        return self.damping[:, None] + self.stiffness[:, None] / (1j * w.reshape(1, -1))

    def initial_state(self) -> np.ndarray:
        return np.ones(self.batch, bool)


class Wall(TipLoad):
    """A unilateral wall at ``gap`` g (m) from the tip's rest position, along +u: the tip
    touches it when ``u > g`` while the wall would push (``k (u - g) + c u' > 0``), and leaves it
    when the force turns tensile. It may touch and leave any number of times.

    Args:
        gap: g, m (may be negative: a wall the tip rests past; 0 < g usual), shape ``(B,)``.
        stiffness: k_c, N/m, > 0.  damping: c_c, N·s/m, >= 0.
    """

    def __init__(self, gap, stiffness, damping) -> None:
        self.offset = np.atleast_1d(np.asarray(gap, dtype=float)).copy()
        if not np.all(np.isfinite(self.offset)):
            raise ValueError("gap must be finite (m)")
        size = len(self.offset)
        self.stiffness = _batch("stiffness", stiffness, "N/m", size, positive=True)
        self.damping = _batch("damping", damping, "N·s/m", size)

    unilateral = True

    def initial_state(self) -> np.ndarray:
        return self.offset < 0


TEST_ROW = (0, 2)
"""The output each regime's switching rule reads first: u when free, F when engaged."""


def _regimes(free: tuple, engaged: tuple, offset: np.ndarray) -> tuple[np.ndarray, ...]:
    """The two regimes' diagonal maps in the stepper's layout: regime first (0 free,
    1 engaged), then real and imaginary parts, records last; the wall offset g folded into a
    constant input. Returns ``lam`` (2, 2, m, B), ``gain`` (2, 2, 3, m, B) on ``[E, Ė, 1]``,
    ``out`` (2, 2, 4, m, B), ``feed`` (2, 4, 3, B) on ``[E, Ė_out, 1]``, ``to_modal``
    (2, 2, m, ns, B) and ``to_state`` (2, 2, ns, m, B).
    """
    m = max(f[0].shape[1] for f in (free, engaged))

    def pad(a: np.ndarray, axis: int | None) -> np.ndarray:  # to m modes along ``axis``
        if axis is None:
            return a
        width = [(0, 0)] * a.ndim
        width[axis] = (0, m - a.shape[axis])
        return np.pad(a, width)

    def parts(a: np.ndarray) -> np.ndarray:  # (2 regimes, B, ...) -> (2, 2 parts, ..., B)
        return np.moveaxis(np.stack([a.real, a.imag], 1), 2, -1)

    lam, gain, out, feed, to_modal, to_state = (
        np.stack([pad(f, axis), pad(g, axis)]) for f, g, axis in
        zip(free, engaged, (1, 1, 2, None, 1, 2), strict=True))
    g = offset[:, None]
    gain = np.stack([gain[..., 0], gain[..., 1], gain[..., 2] * g], 2)
    feed = np.stack([feed[..., 0], feed[..., 3], feed[..., 2] * g], -1)
    return (parts(lam), parts(gain), parts(out), np.moveaxis(feed, 1, -1), parts(to_modal),
            parts(to_state))


@njit(cache=True, nogil=True)
def _step_block(lam, gain, out, feed, to_modal, to_state, e, de_step, de_out, engaged0,
                unilateral, offset, stiffness, damping, cols, values, contact):
    """The stepper, for a block of B records side by side (maps from :func:`_regimes`).

    Each record's modal state ``w`` (m complex) advances by its regime's diagonal map; the
    outputs at step k are read before the step. A unilateral load switches by the rule of
    :class:`TipLoad`, judged on the outputs of the regime it is in; a switch carries the state
    into the other regime's basis through the physical state, with the load's force state
    restarted at 0, and the step is taken in the new regime.

    Args:
        e, de_step, de_out: E (V), its slope over each step and its rate at each sample
            (V/s), shape ``(B, n_steps)``, or ``(1, n_steps)`` shared by the block.
        engaged0: the regime at rest, bool ``(B,)``.
        cols: indices into :data:`OUTPUTS` to record.
        values: written, ``(len(cols), B, n_steps)``; contact: written, bool ``(B, n_steps)``.
    """
    m, bsz = lam.shape[2], lam.shape[3]
    w = np.zeros((2, m, bsz))
    now_lam = np.empty((2, m, bsz))
    now_gain = np.empty((2, 3, m, bsz))
    now_out = np.empty((2, 5, m, bsz))
    now_feed = np.empty((5, 3, bsz))
    engaged = engaged0.copy()
    for b in range(bsz):
        _load(b, 1 if engaged[b] else 0, lam, gain, out, feed, now_lam, now_gain, now_out,
              now_feed)
    ek, dk, ok, y = np.empty(bsz), np.empty(bsz), np.empty(bsz), np.empty(bsz)
    x = np.empty(to_state.shape[2])
    for k in range(e.shape[1]):
        for b in range(bsz):
            src = b if e.shape[0] > 1 else 0
            ek[b], dk[b], ok[b] = e[src, k], de_step[src, k], de_out[src, k]
        if unilateral:
            _output(now_out, now_feed, 4, w, ek, ok, y)
            for b in range(bsz):
                if engaged[b]:
                    new = y[b] >= 0.0
                else:
                    u = y[b] - offset[b]
                    new = u > 0.0 and (stiffness[b] * u + damping[b] * _output_at(
                        now_out, now_feed, 1, w, ek[b], ok[b], b) > 0.0)
                if new != engaged[b]:
                    _switch(b, 1 if new else 0, to_modal, to_state, w, x)
                    _load(b, 1 if new else 0, lam, gain, out, feed, now_lam, now_gain,
                          now_out, now_feed)
                    engaged[b] = new
        for j in range(len(cols)):
            _output(now_out, now_feed, cols[j], w, ek, ok, y)
            for b in range(bsz):
                values[j, b, k] = y[b]
        for b in range(bsz):
            contact[b, k] = engaged[b]
        for j in range(m):
            for b in range(bsz):
                re, im = w[0, j, b], w[1, j, b]
                w[0, j, b] = (now_lam[0, j, b] * re - now_lam[1, j, b] * im
                              + now_gain[0, 0, j, b] * ek[b] + now_gain[0, 1, j, b] * dk[b]
                              + now_gain[0, 2, j, b])
                w[1, j, b] = (now_lam[0, j, b] * im + now_lam[1, j, b] * re
                              + now_gain[1, 0, j, b] * ek[b] + now_gain[1, 1, j, b] * dk[b]
                              + now_gain[1, 2, j, b])


@njit(cache=True)
def _load(b, s, lam, gain, out, feed, now_lam, now_gain, now_out, now_feed):
    """Make regime ``s`` record b's current maps; row 4 of the outputs is its test row."""
    now_lam[:, :, b] = lam[s, :, :, b]
    now_gain[:, :, :, b] = gain[s, :, :, :, b]
    now_out[:, :4, :, b] = out[s, :, :, :, b]
    now_out[:, 4, :, b] = out[s, :, TEST_ROW[s], :, b]
    now_feed[:4, :, b] = feed[s, :, :, b]
    now_feed[4, :, b] = feed[s, TEST_ROW[s], :, b]


@njit(cache=True)
def _switch(b, s, to_modal, to_state, w, x):
    """Carry record b's modal state into regime ``s``'s basis (from the other regime's),
    through the physical state with the load's force state set to 0."""
    ns, m, old = x.shape[0], w.shape[1], 1 - s
    for r in range(ns):
        acc = 0.0
        for j in range(m):
            acc += to_state[old, 0, r, j, b] * w[0, j, b] - to_state[old, 1, r, j, b] * w[1, j, b]
        x[r] = acc
    x[ns - 1] = 0.0
    for j in range(m):
        for p in range(2):
            acc = 0.0
            for r in range(ns):
                acc += to_modal[s, p, j, r, b] * x[r]
            w[p, j, b] = acc


@njit(cache=True)
def _output(now_out, now_feed, row, w, ek, ok, y):
    """Output ``row`` of every record of the block at this step, into ``y`` (B,)."""
    for b in range(y.shape[0]):
        y[b] = now_feed[row, 0, b] * ek[b] + now_feed[row, 1, b] * ok[b] + now_feed[row, 2, b]
    for j in range(w.shape[1]):
        for b in range(y.shape[0]):
            y[b] += now_out[0, row, j, b] * w[0, j, b] - now_out[1, row, j, b] * w[1, j, b]


@njit(cache=True)
def _output_at(now_out, now_feed, row, w, ek, ok, b):
    """Output ``row`` of record b alone."""
    y = now_feed[row, 0, b] * ek + now_feed[row, 1, b] * ok + now_feed[row, 2, b]
    for j in range(w.shape[1]):
        y += now_out[0, row, j, b] * w[0, j, b] - now_out[1, row, j, b] * w[1, j, b]
    return y


def ze_limits(t: np.ndarray) -> np.ndarray:
    """Ze (Ω) of a two-port with its tip free (``t12/t22``) and clamped (``t11/t21``): the two
    limits of the bilinear map Ze(Zm) (physics.md §2), shape ``t.shape[:-2] + (2,)``."""
    return np.stack([t[..., 0, 1] / t[..., 1, 1], t[..., 0, 0] / t[..., 1, 0]], -1)


def truncation_errors(beam: BeamTransducer, omega, most: int | None = None) -> np.ndarray:
    """How far the modal model with n = 1, 2, ... modes is from the one with every mode kept
    (the same modal damping: truncation alone), as the largest relative error over ``omega``
    of Ze with the tip free and with it clamped (:func:`ze_limits`).

    Args:
        beam: the full model.
        omega: rad/s, shape ``(n_freq,)`` (the scene's band).
        most: the largest n (default: every mode of the beam).

    Returns:
        shape ``(most,)``: entry n - 1 is n modes' error (relative, 1).
    """
    errors = _truncation_errors(beam, omega)
    if most is not None:
        check_range("most", most, 1, len(beam.matrices()[2]))
    return np.array([next(errors) for _ in range(most or len(beam.matrices()[2]))])


def fewest_modes(beam: BeamTransducer, omega, tolerance: float) -> tuple[int, np.ndarray]:
    """``n_modes: auto``: the fewest modes whose model stays within ``tolerance`` of the model
    with every mode kept over the band ``omega``, by :func:`truncation_errors` (Ze with the tip
    free and clamped, pointwise relative: the two ends of every tip load's bilinear map
    Ze(Zm); where a truncated mode's resonance falls in the band, both miss it).

    Static correction makes ω -> 0 exact whatever n (HUE(0) is the beam's), so the band need
    hold only the frequencies the scene drives and records. The model with every mode is the
    converged reference of the truncation; the modal damping's own difference from the beam's
    complex modulus (1.3 % in the micro preset's free Ze at 420 Hz, physics.md §9) is not a
    truncation error and does not shrink with n. A tolerance on Ze is not one on a decoder
    trained on another count: ``wtml bench models`` measures both.

    Args:
        beam: the full model.
        omega: the band, rad/s, shape ``(n_freq,)``, sampled densely enough to resolve its
            resonances (log-spaced, a few hundred points per decade).
        tolerance: the largest relative error allowed, in (0, 1).

    Returns:
        the count n and the errors of 1..n modes (the last within ``tolerance``, the one
        before it, where there is one, not).
    """
    check_range("tolerance", tolerance, 0.0, 1.0, low_open=True, high_open=True)
    errors = []
    for err in _truncation_errors(beam, omega):  # every mode kept: error 0, so it ends
        errors.append(err)
        if err <= tolerance:
            break
    return len(errors), np.array(errors)


def _truncation_errors(beam: BeamTransducer, omega):
    """Yield :func:`truncation_errors`' entries for n = 1, 2, ... up to every mode."""
    omega = check_omega(omega)
    n_dof = len(beam.matrices()[2])
    full = ze_limits(ModalTransducer.from_beam(beam, n_dof).transduction_matrix(omega))
    for n in range(1, n_dof + 1):
        model = ModalTransducer.from_beam(beam, n)
        yield float(np.max(np.abs(ze_limits(model.transduction_matrix(omega)) / full - 1)))


def convergence_table(beam: BeamTransducer, omega, n_modes=(1, 2, 3, 4, 6, 10)) -> list[dict]:
    """How the modal T(ω) approaches the full model as modes are added.

    For each n: the largest relative error of any element of T over ``omega`` against the
    model with every mode kept (the same modal damping: truncation alone), against the beam
    (truncation plus the damping-model difference, §9), and the relative error of HUE(0).

    Args:
        omega: rad/s, shape ``(n_freq,)`` (the scene's band).
    """
    omega = check_omega(omega)
    full = ModalTransducer.from_beam(beam, len(beam.matrices()[2])).transduction_matrix(omega)
    exact = beam.transduction_matrix(omega)
    hue = beam.static_tip_displacement_per_volt()
    rows = []
    for n in n_modes:
        model = ModalTransducer.from_beam(beam, n)
        t = model.transduction_matrix(omega)
        rows.append({"n_modes": n,
                     "vs_all_modes": float(np.max(np.abs(t - full) / np.abs(full))),
                     "vs_beam": float(np.max(np.abs(t - exact) / np.abs(exact))),
                     "hue0": float(abs(model.static_tip_displacement_per_volt() / hue - 1))})
    return rows
