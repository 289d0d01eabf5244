"""Friction at the tip of the time-domain transducer: a whisker sweeping sandpaper
(physics.md §11, §12, thesis §4.5).

The tip slides along the surface in its whisking direction u, pressed against it with a normal
force N at a contact angle θ (between the whisker and the surface's normal plane; the surface
carries ``N cos θ``). The force the transducer applies to the surface, along u, is one of three
laws (:data:`LAWS`, chosen per record), plus the asperities::

    coulomb   F = μ_c N cos θ tanh(v / v_r) + c v
    stribeck  F = μ(v) N cos θ tanh(v / v_r) + c v,   μ(v) = μ_c + (μ_s − μ_c) exp(−(v/v_s)²)
    lugre     F = σ0 z + σ1 ż + c v,   ż = v − σ0 |v| z / g(v),   g(v) = μ(v) N cos θ

- Coulomb friction regularised over ``v_r`` (``slip_speed``; its fundamental is in phase with
  V: the describing function ``4 μ N cos θ / (π |V|)`` adds to Re Zm); Stribeck's coefficient
  falls from μ_s at rest to μ_c over ``v_s`` (``stribeck_speed``); LuGre's bristle z sticks
  (``F = σ0 z``, the pre-sliding stiffness σ0, over the pre-sliding distance ``g(0)/σ0``) and
  slides at its steady state ``z = g(v) sign(v)/σ0`` (``F = g(v) sign(v) + c v``);
- a viscous part ``c v`` (LuGre's σ2);
- asperities: grains at random positions ``x_j`` along the path (spacing drawn around the mean
  grain size d), each an impulse ``J_j`` (N·s) along the motion when the tip crosses it, so that
  they arrive at the rate |v|/d. :func:`grains` draws them with ``J = a N cos θ d / v_a``
  (``v_a`` = 1 m/s): their mean force is ``a N cos θ |v| / v_a``, a drag that grows with d
  through ``a(d)``. They are the same for every law.

The force is evaluated once per step from the tip's velocity and position at the sample and held
over the step (the linear part is stepped exactly, in the free tip's eigenbasis):

- Coulomb and Stribeck: a smooth function of v, held at its mid-step extrapolation from the last
  two samples (explicit, second order). Stable where the force's slope ``dF/dv`` stays below
  :func:`largest_stable_slope`, the linearised loop's limit (about ``1 / (dt Σφb²)`` where
  every mode is slow: 0.065 N·s/m at the texture scene's step, 9.8 µs, for the macro WT's 21
  modes, which the faster modes lower to 0.0605): there the slope at rest
  ``μ_s N cos θ / v_r + c`` ≈ 0.03 N·s/m is about half of it; Stribeck's falling branch is a
  negative slope (a growth the scheme follows). Past it the step chatters in the current's
  high band (:meth:`wtml.scenes.texture.TextureScene.least_slip_speed`, which the scene
  checks).
- LuGre: sticking, the bristle is a spring σ0 on the tip (up to ~1.7e4 N/m, ``σ0 dt² Σφb²`` ≈
  2.6 at that step), which explicit feedback would not hold. The force held over the step is
  instead solved implicitly: the step's mean force ``σ0 z̄ + σ1 (z_{k+1} − z_k)/dt + c v̄`` with
  v held at the step's mean ``v̄ = (v_k + v_{k+1})/2``, where v_{k+1} answers the force through
  the exact step (one scalar per record, Newton's method in a bracket). Over the step z relaxes
  exactly to ``g(v̄) sign(v̄)/σ0`` at the rate ``σ0 |v̄| / g(v̄)`` (stiff: ~1e7 /s in sliding), so
  |z| never passes its steady state. Second order; the bristle rings on the tip near each
  reversal, excited by the grains, so that at the texture scene's step halving it moves the
  current's fundamental by up to ~3 × a 0.25 s window's noise: the scene steps LuGre at twice
  that rate (``LUGRE_OVERSAMPLE`` of :mod:`wtml.scenes.texture`), where it is within the noise.

The tests show halving the step moves the fundamental phasors by less than a scene's noise for
each law (at its step) and the order of convergence.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit
from scipy.special import dawsn

from wtml.cores import available_cores
from wtml.physics.stepping import eigenbasis, record_blocks
from wtml.physics.validation import check_range

REFERENCE_SPEED = 1.0
"""v_a, m/s: the speed at which an asperity's impulse J equals ``a N cos θ d / v_a``."""


LAWS = ("coulomb", "stribeck", "lugre")
"""The friction laws; a record's law code is its index here."""


class Friction:
    """Sliding friction at the tip for a batch of B records (arrays of shape ``(B,)``).

    Args:
        mu: Coulomb (kinetic) coefficient μ_c (>= 0).
        normal_force: N, N (>= 0).
        angle: contact angle θ, rad, in [0, π/2).
        slip_speed: v_r, m/s (> 0), the regularisation of sign(v) (Coulomb and Stribeck).
        viscous: c, N·s/m (>= 0) (LuGre's σ2).
        positions: grain positions along the path from the tip's rest position, m, sorted,
            shape ``(B, G)`` (pad with +inf); None: no asperities.
        impulses: each grain's impulse, N·s (>= 0), shape ``(B, G)``.
        law: each record's law, a code (index into :data:`LAWS`), default Coulomb.
        static_ratio: μ_s / μ_c in [1, 3] (Stribeck and LuGre).
        stribeck_speed: v_s, m/s (> 0) (Stribeck and LuGre).
        bristle_stiffness: σ0, N/m (> 0) (LuGre): the pre-sliding distance is ``g(0) / σ0``.
        bristle_damping: σ1, N·s/m (>= 0) (LuGre).
    """

    smooth = True

    def __init__(self, mu, normal_force, angle=0.0, slip_speed=0.01, viscous=0.0,
                 positions=None, impulses=None, *, law=0, static_ratio=1.0,
                 stribeck_speed=5e-3, bristle_stiffness=1e3, bristle_damping=0.0) -> None:
        self.mu = check_range("mu", np.atleast_1d(np.asarray(mu, float)), 0.0, 10.0).copy()
        size = len(self.mu)

        def batch(name, value, lo, hi, unit, **kw):
            arr = np.broadcast_to(np.asarray(value, float), (size,)).copy()
            return check_range(name, arr, lo, hi, unit=unit, **kw)

        self.normal_force = batch("normal_force", normal_force, 0.0, 10.0, "N")
        self.angle = batch("angle", angle, 0.0, np.pi / 2, "rad", high_open=True)
        self.slip_speed = batch("slip_speed", slip_speed, 0.0, 10.0, "m/s", low_open=True)
        self.viscous = batch("viscous", viscous, 0.0, 10.0, "N·s/m")
        codes = np.broadcast_to(np.asarray(law), (size,))
        if not np.issubdtype(codes.dtype, np.integer) or np.any((codes < 0)
                                                                 | (codes >= len(LAWS))):
            raise ValueError(f"law: codes 0..{len(LAWS) - 1} for {list(LAWS)}, got "
                             f"{np.unique(codes).tolist()}")
        self.law = codes.astype(np.int64)
        self.static_ratio = batch("static_ratio", static_ratio, 1.0, 3.0, "1")
        self.stribeck_speed = batch("stribeck_speed", stribeck_speed, 0.0, 10.0, "m/s",
                                    low_open=True)
        self.bristle_stiffness = batch("bristle_stiffness", bristle_stiffness, 0.0, 1e9, "N/m",
                                       low_open=True)
        self.bristle_damping = batch("bristle_damping", bristle_damping, 0.0, 10.0, "N·s/m")
        if positions is None:
            positions, impulses = np.full((size, 1), np.inf), np.zeros((size, 1))
        self.positions = np.ascontiguousarray(np.broadcast_to(np.asarray(positions, float),
                                                              (size, np.shape(positions)[-1])))
        self.impulses = np.ascontiguousarray(np.broadcast_to(np.asarray(impulses, float),
                                                             self.positions.shape))
        if (np.any(self.positions[:, 1:] < self.positions[:, :-1])
                or np.any(np.isnan(self.positions))):
            raise ValueError("positions: grain positions must be sorted along each row (m)")
        check_range("impulses", self.impulses, 0.0, 1.0, unit="N·s")

    @property
    def batch(self) -> int:
        return len(self.mu)

    @property
    def coulomb(self) -> np.ndarray:
        """μ_c N cos θ, N, ``(B,)``: the sliding force's magnitude."""
        return self.mu * self.normal_force * np.cos(self.angle)

    def _ex(self, v: np.ndarray):
        return (slice(None),) + (None,) * (v.ndim - 1)

    def sliding(self, velocity) -> np.ndarray:
        """``μ(v) N cos θ``, N, for v (m/s) of shape ``(B, ...)``: the Stribeck curve (μ_c for
        Coulomb records); LuGre's g(v)."""
        v = np.asarray(velocity, float)
        ex = self._ex(v)
        stribeck = np.where(self.law == 0, 0.0, self.static_ratio - 1)[ex]
        return self.coulomb[ex] * (1 + stribeck * np.exp(-(v / self.stribeck_speed[ex]) ** 2))

    def force(self, velocity) -> np.ndarray:
        """The force in steady sliding at v (m/s), shape ``(B, ...)``, N: ``μ(v) N cos θ
        tanh(v/v_r) + c v`` (Coulomb, Stribeck), ``g(v) sign(v) + c v`` (LuGre)."""
        v = np.asarray(velocity, float)
        ex = self._ex(v)
        shape = np.where((self.law == 2)[ex], np.sign(v), np.tanh(v / self.slip_speed[ex]))
        return self.sliding(v) * shape + self.viscous[ex] * v

    def sweep(self, velocity, dt: float) -> np.ndarray:
        """The force (N) along a prescribed velocity ``(B, n)`` (m/s) at the samples ``k dt``,
        the law stepped as :func:`simulate_friction` steps it (the bristle from rest); no
        asperities."""
        v = np.ascontiguousarray(np.broadcast_to(np.asarray(velocity, float),
                                                 (self.batch, np.shape(velocity)[-1])))
        out = np.empty_like(v)
        _sweep(v, dt, *self._law_arrays(), out)
        return out

    def _law_arrays(self) -> tuple[np.ndarray, ...]:
        return (self.law, self.coulomb, self.slip_speed, self.viscous, self.static_ratio,
                self.stribeck_speed, self.bristle_stiffness, self.bristle_damping)


def largest_stable_slope(model, dt: float) -> float:
    """N·s/m: the steepest force law ``dF/dv`` the explicit Coulomb/Stribeck step holds on
    ``model`` (a :class:`~wtml.physics.modal.ModalTransducer`, free tip) at the step ``dt``
    (s): the largest s at which the linearised loop, the exact step under the force held at
    its mid-step extrapolation ``F_k = s (1.5 v_k − 0.5 v_{k−1})`` against the motion, has
    spectral radius at most 1 (bisection to 1e-6 of s). Where every mode is slow this is
    about ``1 / (dt Σφb²)``; the faster modes, rung within the step, hold less: 0.0574 N·s/m
    for the macro WT's 22 modes (its whisker in 32 elements) at 102.4 kS/s, against
    ``1 / (dt Σφb²)`` = 0.0617."""
    radius, c_b = _loop_radius(model, dt)
    low, high = 0.0, 1.0 / abs(c_b)
    while radius(high) <= STABLE:
        low, high = high, 2.0 * high
    while high - low > 1e-6 * high:
        mid = 0.5 * (low + high)
        low, high = (mid, high) if radius(mid) <= STABLE else (low, mid)
    return low


STABLE = 1.0 + 1e-12
"""The friction loop's largest spectral radius that is stable (the held force's own state
has eigenvalue 1 exactly)."""


def holds_slope(model, dt: float, slope: float) -> bool:
    """Whether the explicit friction step on ``model`` at ``dt`` (s) holds a force law of
    slope ``slope`` (N·s/m) at rest: one eigenvalue problem of :func:`largest_stable_slope`'s
    loop (~1 ms), where the bisection takes ~20; what a scene checks on each device it
    steps."""
    return _loop_radius(model, dt)[0](slope) <= STABLE


def _loop_radius(model, dt: float):
    """The spectral radius of the linearised friction loop as a function of the law's slope
    (:func:`largest_stable_slope`), and the tip's velocity response to the force it applies
    within one step, ``c b`` (m/s per N)."""
    maps = model.step_matrices(dt, 0.0, 0.0, force_input=True)[0]
    ns = maps.shape[1] - 4
    a, b, c = maps[:ns, :ns], maps[:ns, ns + 2], maps[ns + 1, :ns]  # x' = a x + b F; v = c x
    if c @ b >= 0:  # the stepper applies +b F with F = law(v): it must slow the tip
        raise ValueError("model: the tip's velocity does not fall under the force it applies")

    def radius(slope: float) -> float:
        loop = np.zeros((ns + 1, ns + 1))
        loop[:ns, :ns] = a + 1.5 * slope * np.outer(b, c)  # F = law(v) enters as +b F
        loop[:ns, ns] = -0.5 * slope * b
        loop[ns, :ns] = c  # v_{k-1} for the next step
        return float(np.max(np.abs(np.linalg.eigvals(loop))))

    return radius, float(c @ b)


def describing_function(coulomb, speed, static_ratio=1.0, stribeck_speed=1.0) -> np.ndarray:
    """Re Zm of sliding friction at the fundamental, N·s/m: the sliding speed v = V cos ωt
    through ``μ(v) N cos θ sign(v)`` (not regularised): ``4 N cos θ (μ_c + (μ_s − μ_c)
    D(y)/y) / (π |V|)``, ``y = |V|/v_s``, D Dawson's integral (``4 μ N cos θ / (π |V|)`` for
    Coulomb, μ_s = μ_c). The work per cycle of a sliding amplitude A is ``π A |V|`` times it.

    Args:
        coulomb: μ_c N cos θ, N.  speed: |V|, the velocity's amplitude, m/s (> 0).
        static_ratio: μ_s / μ_c.  stribeck_speed: v_s, m/s (> 0).
    """
    speed = check_range("speed", speed, 0.0, np.inf, unit="m/s", low_open=True)
    check_range("stribeck_speed", stribeck_speed, 0.0, np.inf, unit="m/s", low_open=True)
    y = np.asarray(speed, float) / stribeck_speed
    rise = (np.asarray(static_ratio, float) - 1) * dawsn(y) / y
    return 4 * np.asarray(coulomb, float) * (1 + rise) / (np.pi * speed)


def grains(rng: np.random.Generator, size_m: float, reach_m: float, *, spread: float = 0.3,
           asperity: float = 0.0, pressing_n: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """One specimen's grains along the path ``[-reach, reach]``: positions (m, sorted) and
    impulses (N·s), each ``(G,)``.

    Spacings are gamma-distributed with mean ``size_m`` and coefficient of variation ``spread``;
    each grain's own size is ``size_m`` times a log-normal of that spread, and its impulse is
    ``asperity · pressing_n · size / v_a`` (``pressing_n``: N cos θ, N).
    """
    check_range("size_m", size_m, 0.0, 1e-2, unit="m", low_open=True)
    check_range("spread", spread, 0.0, 2.0, low_open=True)
    count = int(np.ceil(2 * reach_m / size_m * 1.2)) + 8
    shape = 1 / spread**2
    gaps = rng.gamma(shape, size_m / shape, count)
    pos = -reach_m + np.cumsum(gaps) - gaps[0] * rng.random()
    pos = pos[pos <= reach_m]
    own = size_m * np.exp(spread * rng.standard_normal(len(pos)) - spread**2 / 2)
    return pos, asperity * pressing_n * own / REFERENCE_SPEED


def pad_grains(rows: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Stack each record's ``(positions, impulses)`` into ``(B, G)`` arrays padded with +inf
    positions and zero impulses."""
    width = max(1, max(len(p) for p, _ in rows))
    pos = np.full((len(rows), width), np.inf)
    imp = np.zeros((len(rows), width))
    for r, (p, j) in enumerate(rows):
        pos[r, :len(p)], imp[r, :len(p)] = p, j
    return pos, imp


def simulate_friction(model, e, de_step, de_out, dt: float, load: Friction, coupling_scale,
                      cols: np.ndarray, dtype, threads: int | None) -> dict[str, np.ndarray]:
    """Step ``model`` (a :class:`~wtml.physics.modal.ModalTransducer`) from rest with
    ``load`` at the tip; the arguments as prepared by its ``simulate``. Returns the recorded
    outputs ``(len(cols), B, n_steps)`` and ``contact`` (always True: the tip slides)."""

    bsz, n_steps = load.batch, e.shape[1]
    lam, gain, out, feed, _, _ = eigenbasis(model.step_matrices(
        dt, np.zeros(bsz), np.zeros(bsz), coupling_scale, force_input=True))

    def parts(a: np.ndarray) -> np.ndarray:  # (B, ...) complex -> (2, ..., B)
        return np.ascontiguousarray(np.moveaxis(np.stack([a.real, a.imag]), 1, -1))

    lam, gain, out = parts(lam), parts(np.moveaxis(gain[..., :3], 2, 1)), parts(out)
    feed = np.ascontiguousarray(np.moveaxis(feed[..., [0, 3, 2]], 0, -1))  # on [E, Ė_out, F]
    values = np.empty((len(cols), bsz, n_steps), dtype)
    start = np.array([np.searchsorted(p, 0.0) for p in load.positions], np.int64)
    blocks = record_blocks(bsz, threads)

    def step(b: slice) -> None:
        own = b if len(e) > 1 else slice(0, 1)
        _step_friction(lam[..., b].copy(), gain[..., b].copy(), out[..., b].copy(),
                       feed[..., b].copy(), *(np.ascontiguousarray(a[own])
                                              for a in (e, de_step, de_out)),
                       *(a[b].copy() for a in load._law_arrays()), load.positions[b],
                       load.impulses[b], start[b].copy(), dt, cols, values[:, b])

    with ThreadPoolExecutor(min(len(blocks), threads or available_cores())) as pool:
        list(pool.map(step, blocks))
    return values


@njit(cache=True, nogil=True)
def _sample_force(code, v, z, coulomb, slip, viscous, ratio, vst, sig0, sig1):
    """One record's law at a sample: the force (N) at velocity v (m/s), bristle state z (m)."""
    if code == 0:
        return coulomb * np.tanh(v / slip) + viscous * v
    mu = coulomb * (1.0 + (ratio - 1.0) * np.exp(-(v / vst) ** 2))
    if code == 1:
        return mu * np.tanh(v / slip) + viscous * v
    zdot = v - sig0 * abs(v) * z / mu if mu > 0 else 0.0
    return sig0 * z + sig1 * zdot + viscous * v


@njit(cache=True, nogil=True)
def _bristle(u, z, dt, coulomb, viscous, ratio, vst, sig0, sig1):
    """LuGre over a step dt with the velocity u (m/s) held: z relaxes exactly from z (m)
    towards ``g(u) sign(u)/σ0`` at the rate ``σ0 |u| / g(u)``. Returns the step's mean force
    ``σ0 z̄ + σ1 (z' − z)/dt + c u`` (N), its derivative in u (N·s/m) and z' at its end (m)."""
    mu_e = np.exp(-(u / vst) ** 2)
    g = coulomb * (1.0 + (ratio - 1.0) * mu_e)
    if g <= 0:
        return viscous * u, viscous, 0.0
    dg = -2.0 * coulomb * (ratio - 1.0) * mu_e * u / vst**2
    x = sig0 * abs(u) * dt / g  # the relaxation over the step
    dx = sig0 * dt * (np.sign(u) * g - abs(u) * dg) / g**2
    if x < 1e-3:  # φ1 = (1 - e^-x)/x and φ2 = (x - 1 + e^-x)/x², by their series
        p1 = 1.0 - x / 2 + x * x / 6 - x**3 / 24
        p2 = 0.5 - x / 6 + x * x / 24 - x**3 / 120
        d1 = -0.5 + x / 3 - x * x / 8 + x**3 / 30
        d2 = -1.0 / 6 + x / 12 - x * x / 40 + x**3 / 180
    else:
        em = np.expm1(-x)
        p1, p2 = -em / x, (x + em) / (x * x)
        d1 = (1.0 + em - p1) / x
        d2 = -(d1 + p2) / x
    decay = 1.0 - x * p1  # e^-x
    z_next = z * decay + u * dt * p1
    z_mean = z * p1 + u * dt * p2
    dz_next = -z * decay * dx + dt * p1 + u * dt * d1 * dx
    dz_mean = z * d1 * dx + dt * p2 + u * dt * d2 * dx
    held = sig0 * z_mean + sig1 * (z_next - z) / dt + viscous * u
    return held, sig0 * dz_mean + sig1 * dz_next / dt + viscous, z_next


@njit(cache=True, nogil=True)
def _implicit_bristle(v0, v1, answer, guess, z, dt, coulomb, viscous, ratio, vst, sig0, sig1):
    """LuGre's force F (N) held over a step whose velocity runs from v0 (m/s) to ``v1 + answer
    F`` (v1: where it would end without F; answer < 0: the force the tip applies slows it), the
    bristle stepped at the mean of the two; solved by Newton's method from ``guess`` (N) kept
    within a bracket (bisection where a step leaves it). Returns F and z at the step's end
    (m)."""
    bound = (coulomb * ratio * (1.0 + 2.0 * sig1 / (sig0 * dt))
             + viscous * (abs(v0) + abs(v1))) / max(1.0 - viscous * abs(answer), 1e-3)
    lo, hi = -1.001 * bound - 1e-300, 1.001 * bound + 1e-300
    f = min(max(guess, lo), hi)
    for _ in range(60):
        held, dheld, _ = _bristle(0.5 * (v0 + v1 + answer * f), z, dt, coulomb, viscous,
                                  ratio, vst, sig0, sig1)
        r = f - held  # negative below the root, positive above it
        if r < 0:
            lo = f
        else:
            hi = f
        d = 1.0 - 0.5 * answer * dheld
        nxt = f - r / d if d > 0 else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        done = abs(nxt - f) <= 1e-14 * bound or hi - lo <= 1e-14 * bound
        f = nxt
        if done:
            break
    return f, _bristle(0.5 * (v0 + v1 + answer * f), z, dt, coulomb, viscous, ratio, vst, sig0,
                       sig1)[2]


@njit(cache=True, nogil=True)
def _sweep(v, dt, law, coulomb, slip, viscous, ratio, vst, sig0, sig1, out):
    """The force ``out`` (B, n) along the prescribed velocity ``v`` (B, n) (:meth:`Friction.
    sweep`): LuGre's bristle stepped at each step's mean velocity."""
    for b in range(v.shape[0]):
        z = 0.0
        for k in range(v.shape[1]):
            out[b, k] = _sample_force(law[b], v[b, k], z, coulomb[b], slip[b], viscous[b],
                                      ratio[b], vst[b], sig0[b], sig1[b])
            if law[b] == 2 and k + 1 < v.shape[1]:
                z = _bristle(0.5 * (v[b, k] + v[b, k + 1]), z, dt, coulomb[b], viscous[b],
                             ratio[b], vst[b], sig0[b], sig1[b])[2]


@njit(cache=True, nogil=True)
def _step_friction(lam, gain, out, feed, e, de_step, de_out, law, coulomb, slip, viscous,
                   ratio, vst, sig0, sig1, positions, impulses, start, dt, cols, values):
    """The friction stepper for a block of B records side by side, in the free tip's
    eigenbasis: ``lam`` (2, m, B), ``gain`` (2, 3, m, B) on ``[E, Ė, F]``, ``out`` (2, 4, m, B)
    and ``feed`` (4, 3, B) on ``[E, Ė_out, F]`` for the outputs (u, v, F, i). At each sample
    the force is evaluated from v and from the grains the tip crosses during the coming step
    (by ``u + v dt``, u without the force's own residual part: the impulse lands in the step
    that holds the crossing, not one step late) and recorded. Held over the step with the
    grains' impulse: Coulomb and Stribeck, their force extrapolated to mid-step from the last
    two samples (second order); LuGre, the step's mean force with v held at the step's mean
    ``(v_k + v_{k+1})/2``, v_{k+1} answering the force (implicit: the stiff bristle is no
    explicit feedback), solved once the state has been advanced without it.

    Args:
        law, coulomb, slip, viscous, ratio, vst, sig0, sig1: ``(B,)``, as
            :meth:`Friction._law_arrays`.
        positions, impulses: ``(B, G)`` grains; start: the grains below u = 0, ``(B,)``.
        values: written, ``(len(cols), B, n_steps)``.
    """
    m, bsz = lam.shape[1], lam.shape[2]
    n_steps = e.shape[1]
    w = np.zeros((2, m, bsz))
    ptr = start.copy()
    force = np.zeros(bsz)
    smooth = np.zeros(bsz)  # the law's force at the last sample
    vel = np.zeros(bsz)  # the velocity at this sample
    z = np.zeros(bsz)  # LuGre's bristles
    y = np.zeros(4)
    n_grain = positions.shape[1]
    implicit = np.any(law == 2)
    explicit = 0.0 if implicit else 1.0
    grain = np.zeros(bsz)  # the grains' impulse over the coming step / dt
    held = np.zeros(bsz)  # LuGre's force held over the last step
    answer = np.zeros(bsz)  # ∂v_{k+1}/∂F: the velocity's answer to a held force, m/s/N
    for b in range(bsz):
        for j in range(m):
            answer[b] += out[0, 1, j, b] * gain[0, 2, j, b] - out[1, 1, j, b] * gain[1, 2, j, b]
    for k in range(n_steps):
        for b in range(bsz):
            src = b if e.shape[0] > 1 else 0
            ek, ok = e[src, k], de_out[src, k]
            for r in (0, 1, 3):  # u, v, i; F (2) is the law's, below
                acc = feed[r, 0, b] * ek + feed[r, 1, b] * ok
                for j in range(m):
                    acc += out[0, r, j, b] * w[0, j, b] - out[1, r, j, b] * w[1, j, b]
                y[r] = acc
            v = y[1]
            u = y[0] + v * dt  # where the tip will be at the next sample
            kick = 0.0
            while ptr[b] < n_grain and positions[b, ptr[b]] <= u:
                kick += impulses[b, ptr[b]]
                ptr[b] += 1
            while ptr[b] > 0 and positions[b, ptr[b] - 1] > u:
                kick -= impulses[b, ptr[b] - 1]
                ptr[b] -= 1
            now = _sample_force(law[b], v, z[b], coulomb[b], slip[b], viscous[b], ratio[b],
                                vst[b], sig0[b], sig1[b])
            y[2] = now + kick / dt
            y[0] += feed[0, 2, b] * y[2]
            # Coulomb, Stribeck: held over the step at the mid-step extrapolation
            force[b] = (1.5 * now - 0.5 * smooth[b] if k > 0 else now) + kick / dt
            smooth[b], vel[b], grain[b] = now, v, kick / dt
            for c in range(len(cols)):
                values[c, b, k] = y[cols[c]]
        for j in range(m):  # the state advanced (with LuGre in the block: without the force)
            for b in range(bsz):
                src = b if e.shape[0] > 1 else 0
                ek, dk, fk = e[src, k], de_step[src, k], force[b] * explicit
                re, im = w[0, j, b], w[1, j, b]
                w[0, j, b] = (lam[0, j, b] * re - lam[1, j, b] * im + gain[0, 0, j, b] * ek
                              + gain[0, 1, j, b] * dk + gain[0, 2, j, b] * fk)
                w[1, j, b] = (lam[0, j, b] * im + lam[1, j, b] * re + gain[1, 0, j, b] * ek
                              + gain[1, 1, j, b] * dk + gain[1, 2, j, b] * fk)
        if implicit:
            nxt = min(k + 1, n_steps - 1)
            for b in range(bsz):
                if law[b] != 2:
                    continue
                src = b if e.shape[0] > 1 else 0
                acc = feed[1, 0, b] * e[src, nxt] + feed[1, 1, b] * de_out[src, nxt]
                for j in range(m):
                    acc += out[0, 1, j, b] * w[0, j, b] - out[1, 1, j, b] * w[1, j, b]
                held[b], z[b] = _implicit_bristle(vel[b], acc + answer[b] * grain[b],
                                                  answer[b], held[b], z[b], dt, coulomb[b],
                                                  viscous[b], ratio[b], vst[b], sig0[b],
                                                  sig1[b])
                force[b] = held[b] + grain[b]
            for j in range(m):
                for b in range(bsz):
                    w[0, j, b] = w[0, j, b] + gain[0, 2, j, b] * force[b]
                    w[1, j, b] = w[1, j, b] + gain[1, 2, j, b] * force[b]
