"""Euler–Bernoulli finite elements with piezoelectric coupling (physics.md §3).

A transducer is a cantilever clamped at x = 0, made of segments in series along x (a
bimorph, an adhesive block, a whisker), with point masses at nodes. Hermite-cubic elements,
two DOFs per node (w, θ), consistent mass. Nodal equations, with F the force the transducer
applies to the load at the tip and E the voltage::

    D(ω) r = -b F + Θ E,     Q = Θᵀ r + Cp E,     D(ω) = K - ω² M   (K complex with loss)

b picks the tip's w, Θ is the piezo coupling and Cp the clamped capacitance. Then
``U = -a F + β E``, ``Q = -β F + δ E`` with ``a = bᵀD⁻¹b``, ``β = bᵀD⁻¹Θ``,
``δ = Cp + ΘᵀD⁻¹Θ``, and with ``V = jωU``, ``I = jωQ``::

    t11 = a/β,   t12 = 1/(jωβ),   t21 = jω(aδ - β²)/β,   t22 = δ/β,

so det T = 1 identically (D symmetric). Losses: a complex modulus per segment
(``E (1 + jη)``), optional Rayleigh damping ``C = αM + βK`` (added as ``jωC``), and dielectric
loss ``Cp (1 - j tanδ)``.

A contact on the shaft at x (a spring k between the whisker and the ground) is the rank-one
change ``D -> D + k n nᵀ`` with n the Hermite shape functions at x, so it needs no remeshing:
by Sherman–Morrison, with ``G = D⁻¹`` and ``g = nᵀGn``, every quadratic form ``pᵀD⁻¹q`` becomes
``pᵀGq - k (pᵀGn)(nᵀGq) / (1 + k g)``, whose rigid limit (k -> inf) is
``pᵀGq - (pᵀGn)(nᵀGq)/g``. One inverse per frequency then serves any number of contacts.

Beam-level piezo constants (Table 3.2): a PZT layer of thickness tp, width b and mid-plane
at distance z from the neutral axis, under a field E/tp, pushes with the stress ``e31 E/tp``,
``e31 = d31/s11E`` (the 1-D, plane-stress piezo constant), and so bends the beam with the
moment ``e31 b z E``. The two layers of a bimorph bend it the same way: the coupling is
``Γ = 2 e31 b z`` per volt for parallel poling (both layers see E) and half that for series
(each sees E/2). The layer's own modulus is ``1/s11E``. The clamped capacitance uses ε33S of
Table 3.2 (the thesis gives no ε33T; the beam-level permittivity ε33T - d31²/s11E lies
between the two, so Cp is a slight underestimate): ``Cp = ε33S b L / tp`` per layer, the two
layers in parallel (parallel poling) or in series. Each segment's coupling enters Θ as the
moments ``∓Γ`` at its two ends (a uniform moment has no distributed load).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wtml.physics.structure import Structure
from wtml.physics.validation import check_omega, check_range


@dataclass(frozen=True)
class Segment:
    """A uniform beam segment.

    Attributes:
        length: m.
        bending_stiffness: EI in N·m² (real; loss in ``loss_factor``).
        mass_per_length: ρA in kg/m.
        loss_factor: hysteretic η, ``EI (1 + jη)``.
        coupling: Γ in N·m/V (0 for a passive segment).
        capacitance: clamped capacitance Cp of the segment in F (0 for a passive one).
        elements: number of finite elements.
        name: a label for reports.
    """

    length: float
    bending_stiffness: float
    mass_per_length: float
    loss_factor: float = 0.0
    coupling: float = 0.0
    capacitance: float = 0.0
    elements: int = 8
    name: str = ""

    def __post_init__(self) -> None:
        for f, unit in (("length", "m"), ("bending_stiffness", "N·m²"),
                        ("mass_per_length", "kg/m")):
            check_range(f"{self.name or 'segment'}.{f}", getattr(self, f), 0.0, np.inf,
                        unit=unit, low_open=True, high_open=True)
        check_range(f"{self.name or 'segment'}.loss_factor", self.loss_factor, 0.0, 1.0)
        check_range(f"{self.name or 'segment'}.elements", self.elements, 1, 10_000)

    def refined(self, factor: int) -> Segment:
        """The same segment with ``factor`` times as many elements."""
        return Segment(self.length, self.bending_stiffness, self.mass_per_length,
                       self.loss_factor, self.coupling, self.capacitance,
                       self.elements * factor, self.name)


def rectangular(name: str, length: float, width: float, thickness: float,
                youngs_modulus: float, density: float, *, loss_factor: float = 0.0,
                elements: int = 8) -> Segment:
    """A passive rectangular segment bending across ``thickness``."""
    return Segment(length, youngs_modulus * width * thickness**3 / 12,
                   density * width * thickness, loss_factor, elements=elements, name=name)


def round_rod(name: str, length: float, radius: float, youngs_modulus: float, density: float,
              *, loss_factor: float = 0.0, elements: int = 8) -> Segment:
    """A passive round segment (a whisker), ``I = π r⁴/4``."""
    return Segment(length, youngs_modulus * np.pi * radius**4 / 4, density * np.pi * radius**2,
                   loss_factor, elements=elements, name=name)


@dataclass(frozen=True)
class PiezoMaterial:
    """Piezoceramic constants (Table 3.2) in SI: d31 in m/V, s11E in m²/N, ε33S in F/m."""

    d31: float = -2.74e-10
    s11e: float = 1.65e-11
    eps33s: float = 3400 * 8.8541878128e-12
    density: float = 7500.0
    loss_factor: float = 0.0


def bimorph(name: str, length: float, width: float, t_piezo: float, t_substrate: float,
            substrate_modulus: float, substrate_density: float, *,
            piezo: PiezoMaterial = PiezoMaterial(), poling: str = "series",
            loss_factor: float = 0.0, elements: int = 8) -> Segment:
    """A PZT / substrate / PZT bimorph segment (module docstring for the constants).

    Args:
        t_piezo: thickness of each PZT layer, m; t_substrate: the middle layer, m (may be 0).
        poling: ``"series"`` or ``"parallel"``.
    """
    if poling not in ("series", "parallel"):
        raise ValueError(f"poling must be 'series' or 'parallel', got {poling!r}")
    e_p = 1 / piezo.s11e
    z = (t_substrate + t_piezo) / 2  # layer mid-plane to the neutral axis (symmetric stack)
    ei = (substrate_modulus * width * t_substrate**3 / 12
          + 2 * e_p * width * (t_piezo**3 / 12 + t_piezo * z**2))
    rho_a = width * (substrate_density * t_substrate + 2 * piezo.density * t_piezo)
    e31 = piezo.d31 / piezo.s11e
    layer_c = piezo.eps33s * width * length / t_piezo
    coupling = abs(2 * e31 * width * z) * (1.0 if poling == "parallel" else 0.5)
    cap = 2 * layer_c if poling == "parallel" else layer_c / 2
    return Segment(length, ei, rho_a, loss_factor, coupling, cap, elements, name)


@dataclass(frozen=True)
class PointMass:
    """A rigid mass (kg) at ``position`` (m from the clamp), e.g. the macro WT's clamp."""

    position: float
    mass: float


def _element_matrices(length: float, ei: complex, rho_a: float) -> tuple[np.ndarray, np.ndarray]:
    h = length
    k = ei / h**3 * np.array([[12, 6 * h, -12, 6 * h], [6 * h, 4 * h**2, -6 * h, 2 * h**2],
                              [-12, -6 * h, 12, -6 * h], [6 * h, 2 * h**2, -6 * h, 4 * h**2]])
    m = rho_a * h / 420 * np.array([[156, 22 * h, 54, -13 * h],
                                    [22 * h, 4 * h**2, 13 * h, -3 * h**2],
                                    [54, 13 * h, 156, -22 * h],
                                    [-13 * h, -3 * h**2, -22 * h, 4 * h**2]])
    return k, m


def hermite(xi: np.ndarray, h: float) -> np.ndarray:
    """Cubic Hermite shape functions at ``xi`` in [0, 1] of an element of length h,
    shape ``xi.shape + (4,)`` for the DOFs (w0, θ0, w1, θ1)."""
    xi = np.asarray(xi, dtype=float)
    return np.stack([1 - 3 * xi**2 + 2 * xi**3, h * (xi - 2 * xi**2 + xi**3),
                     3 * xi**2 - 2 * xi**3, h * (-xi**2 + xi**3)], -1)


def _spring_to_ground(forms, nb, nt, gg, stiff):
    """Sherman–Morrison update (module docstring) of the free forms ``(a, β, δ)`` by contacts
    of stiffness ``stiff`` ``(n_contacts,)`` N/m (``inf`` rigid) with ``nb = bᵀGn``,
    ``nt = ΘᵀGn``, ``gg = nᵀGn``, each ``(n_contacts, n_freq)``."""
    a, beta, delta = forms
    stiff = np.asarray(stiff, dtype=float)[:, None]
    rigid = np.isinf(stiff)
    finite = np.where(rigid, 0.0, stiff)
    factor = np.where(rigid, 1.0 / gg, finite / (1 + finite * gg))
    return a - factor * nb**2, beta - factor * nb * nt, delta - factor * nt**2


@dataclass(frozen=True)
class BeamTransducer(Structure):
    """A clamped piezo-coupled beam with the mechanical port at its free end (the whisker tip).

    Attributes:
        segments: from the clamp to the tip.
        masses: point masses (moved to the nearest node).
        tan_delta: dielectric loss tangent.
        rayleigh: (α in 1/s, β in s) of ``C = αM + βK`` (default none).
    """

    segments: tuple[Segment, ...]
    masses: tuple[PointMass, ...] = ()
    tan_delta: float = 0.0
    rayleigh: tuple[float, float] = (0.0, 0.0)
    _cache: dict = field(default_factory=dict, repr=False, compare=False, hash=False)

    @property
    def length(self) -> float:
        """Clamp to tip, m."""
        return float(sum(s.length for s in self.segments))

    @property
    def capacitance(self) -> complex:
        """Clamped capacitance with dielectric loss, F."""
        return sum(s.capacitance for s in self.segments) * (1 - 1j * self.tan_delta)

    def refined(self, factor: int) -> BeamTransducer:
        return BeamTransducer(tuple(s.refined(factor) for s in self.segments), self.masses,
                              self.tan_delta, self.rayleigh)

    def nodes(self) -> np.ndarray:
        """Node positions from the clamp, m, shape ``(n_nodes,)``."""
        xs = [0.0]
        for s in self.segments:
            xs += list(xs[-1] + s.length * np.arange(1, s.elements + 1) / s.elements)
        return np.array(xs)

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``K`` (complex, with loss), ``M`` and ``Θ`` with the clamped node's DOFs removed;
        ``K, M`` of shape ``(n_dof, n_dof)``, ``Θ`` of shape ``(n_dof,)``; DOF 2i is w and
        2i+1 is θ of node i+1."""
        if "kmt" in self._cache:
            return self._cache["kmt"]
        nodes = self.nodes()
        n = 2 * len(nodes)
        k, m, theta = np.zeros((n, n), complex), np.zeros((n, n)), np.zeros(n)
        e = 0
        for s in self.segments:
            h = s.length / s.elements
            ke, me = _element_matrices(h, s.bending_stiffness * (1 + 1j * s.loss_factor),
                                       s.mass_per_length)
            first = e
            for _ in range(s.elements):
                idx = slice(2 * e, 2 * e + 4)
                k[idx, idx] += ke
                m[idx, idx] += me
                e += 1
            theta[2 * first + 1] -= s.coupling
            theta[2 * e + 1] += s.coupling
        for pm in self.masses:
            i = int(np.argmin(np.abs(nodes - pm.position)))
            m[2 * i, 2 * i] += pm.mass
        out = (k[2:, 2:], m[2:, 2:], theta[2:])
        self._cache["kmt"] = out
        return out

    def natural_frequencies(self, count: int = 3) -> np.ndarray:
        """Lowest natural frequencies in Hz, tip free, electrodes shorted, loss ignored."""
        from scipy.linalg import eigh

        k, m, _ = self.matrices()
        w2 = eigh(k.real, m, eigvals_only=True, subset_by_index=[0, count - 1])
        return np.sqrt(w2) / (2 * np.pi)

    def dynamic_stiffness(self, omega: np.ndarray) -> np.ndarray:
        """``D(ω) = K - ω² M + jω (αM + βK)``, N/m, shape ``(n_freq, n_dof, n_dof)`` for
        ``omega`` (rad/s) of shape ``(n_freq,)``: electrodes shorted, tip free."""
        k, m, _ = self.matrices()
        alpha_r, beta_r = self.rayleigh
        w = np.asarray(omega)[:, None, None]
        d = k[None] - w**2 * m[None]
        if alpha_r or beta_r:
            d = d + 1j * w * (alpha_r * m + beta_r * k)[None]
        return d

    def _forms(self, omega: np.ndarray, contact=None):
        """``a, β, δ`` of shape ``(n_freq,)`` or, with ``contact = (n_vectors, k)`` for
        ``n_vectors (n_contacts, n_dof)``, shape ``(n_contacts, n_freq)``."""
        theta = self.matrices()[2]
        tip = np.zeros(len(theta))
        tip[-2] = 1.0
        d = self.dynamic_stiffness(omega)
        # D⁻¹ applied to b, Θ and each contact's n only (one LU per frequency, not an inverse)
        vecs, stiff = contact if contact is not None else (np.zeros((0, len(theta))), None)
        rhs = np.concatenate([tip[None], theta[None], vecs]).T  # (n_dof, 2 + n_contacts)
        x = np.linalg.solve(d, np.broadcast_to(rhs, (len(omega),) + rhs.shape))
        gb, gt = x[:, :, 0], x[:, :, 1]  # (n_freq, n_dof); G symmetric: Gb[-2] = bᵀGΘ etc.
        a, beta, delta = gb[:, -2], gt[:, -2], self.capacitance + gt @ theta
        if contact is None:
            return a, beta, delta
        gn = np.moveaxis(x[:, :, 2:], -1, 0)  # (n_contacts, n_freq, n_dof)
        nb, nt = gn[..., -2], gn @ theta
        gg = np.einsum("cfi,ci->cf", gn, vecs)
        return _spring_to_ground((a, beta, delta), nb, nt, gg, stiff)

    def contact_vectors(self, positions) -> np.ndarray:
        """Shape-function vectors n of contacts at ``positions`` (m from the clamp),
        shape ``(n_contacts, n_dof)``."""
        positions = check_range("contact position", positions, 0.0, self.length, unit="m",
                                low_open=True)
        nodes = self.nodes()
        el = np.clip(np.searchsorted(nodes, positions, side="right") - 1, 0, len(nodes) - 2)
        h = nodes[el + 1] - nodes[el]
        shape = hermite((positions - nodes[el]) / h, 1.0) * np.stack(
            [np.ones_like(h), h, np.ones_like(h), h], -1)
        vecs = np.zeros((positions.size, 2 * len(nodes)))
        for j in range(4):
            vecs[np.arange(positions.size), 2 * el + j] = shape[:, j]
        return vecs[:, 2:]

    @staticmethod
    def _t_from_forms(omega, a, beta, delta) -> np.ndarray:
        jw = 1j * omega
        t = np.empty(np.shape(a) + (2, 2), dtype=complex)
        t[..., 0, 0] = a / beta
        t[..., 0, 1] = 1 / (jw * beta)
        t[..., 1, 0] = jw * (a * delta - beta**2) / beta
        t[..., 1, 1] = delta / beta
        return t

    def transduction_matrix(self, omega) -> np.ndarray:
        """T(ω) at the tip with no contact, shape ``(n_freq, 2, 2)``, det T = 1."""
        omega = np.atleast_1d(check_omega(omega))
        return self._t_from_forms(omega, *self._forms(omega))

    def contact_transduction_matrix(self, omega, positions, stiffness) -> np.ndarray:
        """T(ω) at the tip with a shaft contact (spring to ground) at each of ``positions``
        (m from the clamp) of stiffness ``stiffness`` (N/m, ``inf`` rigid; broadcast against
        positions), shape ``(n_contacts, n_freq, 2, 2)``."""
        omega = np.atleast_1d(check_omega(omega))
        vecs = self.contact_vectors(positions)
        stiff = np.broadcast_to(np.asarray(stiffness, dtype=float), (len(vecs),))
        check_range("contact stiffness", stiff, 0.0, np.inf, unit="N/m")
        return self._t_from_forms(omega, *self._forms(omega, (vecs, stiff)))

    def contact_as_tip_load(self, omega, positions, stiffness) -> np.ndarray:
        """The 2×2 path's stand-in for a shaft contact: the spring seen at the tip through the
        free structure's deflection under a tip force, ``Zm = ψ² k / (jω)`` with
        ``ψ(x, ω) = nᵀD⁻¹b / bᵀD⁻¹b`` (the deflection at the contact per tip deflection), so
        that ``ze_from_zm(T_free, Zm)`` needs T once per frequency and ψ per contact.

        It is exact for a contact at the tip (ψ = 1). Elsewhere, against the exact rank-one
        update (module docstring, ``a = bᵀGb``): the tip's receptance agrees to first order
        in k (``k (nᵀGb)²`` both), but the coupling moves by ``k ψ² a β`` instead of
        ``k (nᵀGb)(nᵀGΘ)`` (the piezo's drive shape at the contact is not the tip force's),
        and ``1 + k ψ² a`` replaces ``1 + k nᵀGn`` (the contact point's compliance beyond the
        tip force's shape is left out), so a rigid contact anywhere clamps the tip
        (``Zm = inf``). What that costs a radial decoder: ``wtml bench models``.

        Args:
            omega: rad/s, shape ``(n_freq,)``.
            positions: contact positions, m from the clamp, shape ``(n,)``.
            stiffness: N/m (``inf`` rigid), broadcast against ``positions``.

        Returns:
            Zm in N·s/m, complex ``(n, n_freq)`` (``inf`` for a rigid contact).
        """
        omega = np.atleast_1d(check_omega(omega))
        vecs = self.contact_vectors(positions)
        stiff = np.broadcast_to(np.asarray(stiffness, dtype=float), (len(vecs),))
        check_range("contact stiffness", stiff, 0.0, np.inf, unit="N/m")
        tip = np.zeros(vecs.shape[1])
        tip[-2] = 1.0
        gb = np.linalg.solve(self.dynamic_stiffness(omega),
                             np.broadcast_to(tip[:, None], (len(omega), len(tip), 1)))[..., 0]
        psi = vecs @ gb.T / gb[:, -2]  # (n, n_freq)
        rigid = np.isinf(stiff)[:, None]
        zm = np.where(rigid, 0.0, stiff[:, None]) * psi**2 / (1j * omega)
        return np.where(rigid, np.inf + 0j, zm)

    def static_tip_displacement_per_volt(self) -> float:
        """``U/E`` at ω -> 0 with a free tip, m/V (the thesis's HUE(0))."""
        k, _, theta = self.matrices()
        return float(np.linalg.solve(k.real, theta)[-2])


def device_forms(transducers, omega, chunk: int = 64) -> tuple[np.ndarray, ...]:
    """For transducers of one mesh (the same element counts, e.g. a preset's manufacturing
    spread): ``G = D⁻¹`` ``(n_dev, n_dof, n_dof, n_freq)`` (frequency last), ``Gb`` and
    ``GΘ`` ``(n_dev, n_dof, n_freq)``, and the free forms ``a, β, δ`` ``(n_dev, n_freq)``;
    batched inverses, ``chunk`` transducers at a time (small temporaries)."""
    omega = np.atleast_1d(check_omega(omega))
    k, m, theta = (np.stack(x) for x in zip(*(t.matrices() for t in transducers), strict=True))
    rayleigh = np.array([t.rayleigh for t in transducers])[:, :, None, None, None]
    w = omega[None, :, None, None]
    g = np.empty(k.shape + omega.shape, dtype=complex)
    for s in range(0, len(k), chunk):
        ks, ms, r = k[s:s + chunk, None], m[s:s + chunk, None], rayleigh[s:s + chunk]
        d = ks - w**2 * ms
        if np.any(r):
            d = d + 1j * w * (r[:, 0] * ms + r[:, 1] * ks)
        g[s:s + chunk] = np.moveaxis(np.linalg.inv(d), 1, -1)  # symmetric in the DOFs
    g_tip, g_theta = g[:, -2], np.einsum("dijf,dj->dif", g, theta)
    cap = np.array([t.capacitance for t in transducers])[:, None]
    free = (g_tip[:, -2], g_theta[:, -2], cap + np.einsum("dif,di->df", g_theta, theta))
    return g, g_tip, g_theta, free


def contact_transduction_matrices(transducers, which, omega, positions, stiffness, *,
                                  forms: tuple | None = None) -> np.ndarray:
    """T(ω) with a shaft contact for records on several transducers of one mesh: record c
    has its contact on ``transducers[which[c]]`` at ``positions[c]`` (m from the clamp) with
    ``stiffness[c]`` (N/m, ``inf`` rigid). One batched inverse per transducer and frequency
    (:func:`device_forms`, or ``forms`` where already computed); each record then reads the 4
    DOFs of its contact's element.
    Shape ``(n_contacts, n_freq, 2, 2)``, the same as
    :meth:`BeamTransducer.contact_transduction_matrix` of each record's transducer."""
    omega = np.atleast_1d(check_omega(omega))
    which = np.asarray(which, dtype=int)
    positions = np.asarray(positions, dtype=float)
    stiff = np.broadcast_to(np.asarray(stiffness, dtype=float), positions.shape)
    check_range("contact stiffness", stiff, 0.0, np.inf, unit="N/m")
    g, g_tip, g_theta, free = forms or device_forms(transducers, omega)
    nodes = np.stack([t.nodes() for t in transducers])
    check_range("contact position", positions, 0.0, float(nodes[which, -1].max()), unit="m",
                low_open=True)
    rec = nodes[which]  # (n, n_nodes)
    el = np.clip((rec <= positions[:, None]).sum(1) - 1, 0, nodes.shape[1] - 2)
    rows = np.arange(len(which))
    x0, h = rec[rows, el], rec[rows, el + 1] - rec[rows, el]
    shape = hermite((positions - x0) / h, 1.0) * np.stack(
        [np.ones_like(h), h, np.ones_like(h), h], -1)  # (n, 4)
    dof = 2 * el[:, None] + np.arange(4) - 2  # the clamped node's DOFs are removed
    shape = np.where(dof >= 0, shape, 0.0)
    dof = np.maximum(dof, 0)
    dev = which[:, None]
    nb = (g_tip[dev, dof] * shape[..., None]).sum(1)
    nt = (g_theta[dev, dof] * shape[..., None]).sum(1)
    block = g[dev[..., None], dof[:, :, None], dof[:, None, :]]  # (n, 4, 4, n_freq)
    gg = (block * (shape[:, :, None] * shape[:, None, :])[..., None]).sum((1, 2))
    forms = _spring_to_ground(tuple(f[which] for f in free), nb, nt, gg, stiff)
    return BeamTransducer._t_from_forms(omega, *forms)
