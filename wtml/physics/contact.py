"""Contact laws for a wall at the tip, stepped implicitly (physics.md §12).

A wall at ``g`` (m) along +u pushes back on the tip with a force ``F = f(δ, δ')`` of the
penetration ``δ = u - g`` and its rate ``δ' = u' - g'``, zero where ``δ <= 0`` and never
tensile. The family (:data:`LAWS`), each set by its tangent stiffness ``k_ref`` (N/m) at a
reference penetration ``δ_ref`` (m), so that all share the thesis's ~5 N/m there:

- ``linear``: ``F = k_ref δ + c δ'`` while that is compressive (the switched
  :class:`~wtml.physics.modal.Wall`'s law);
- ``power``: ``F = K δ^n``, n in [1, 1.5], ``K = k_ref δ_ref^(1-n) / n``;
- ``hunt_crossley``: ``F = K δ^n (1 + α δ')`` clipped at 0 (no force jump at touch or
  release), α in s/m;
- ``mount_hertz``: a linear mount ``k_m`` in series with a Hertz contact,
  ``δ = F/k_m + (F/K_h)^(2/3)``; ``K_h`` such that the combined tangent at ``δ_ref`` is
  ``k_ref`` (:func:`hertz_constant`).

Tangential friction along the wall (``friction`` μ > 0). Geometry: the whisker is a cantilever
along x (clamp at x = 0, tip at x = L), the tip whisks along y (its deflection u), the wall is
the plane y = g. A section of the beam turns with the slope θ = ∂w/∂x (Euler–Bernoulli), so a
point of the section at y = ρ from the axis moves along x by ``-ρ θ``; and the whole tip moves
along x by the foreshortening ``-½ ∫₀ᴸ w'² dx`` of the deflected shape. The tip touches the
wall with its surface, at ρ = half the whisker's thickness (25 µm for the micro whisker), so the
contact point slides along the wall at

    v_c = -ρ θ' - ∫ w' ẇ' dx ≈ -ρ θ' = -ρ φs·q'      (φs: the kept modes' tip slope)

and Coulomb friction, regularised like the texture's (:mod:`wtml.physics.friction`), acts on
the tip along x: ``T = -μ F_n tanh(v_c / v_s)`` (F_n >= 0 the wall's normal force). Its virtual
work ``T δx_c = -ρ T φs·δq`` makes it a moment ``-ρ T`` on the tip's section: in the modal
equations a generalised force ``ψ T`` with ``ψ = -ρ φs`` beside the normal force's ``-φb F``,

    q'' + 2ζΩ q' + Ω² q = φθ E - φb F + ψ T,      T v_c = -μ F_n |v_c| tanh(|v_c|/v_s) <= 0,

so it only ever takes energy out: the work per cycle is ``-∮ μ F_n |v_c| dt`` where
``|v_c| >> v_s``. Assumptions: (1) the linear, offset term only. The foreshortening's rate,
from the beam's own geometric stiffness along a contact held at g while the whisk goes on (and
per mode), is 0.7–30 % of the offset term's (larger at near walls, where the whisker bends
back): the sliding speed is that much uncertain and it would make ψ depend on the state.
(2) The friction acts through the kept modes (no static correction of the slope port). (3)
The wall is the plane y = g: its normal force stays along y whatever the tip's slope (up to
2.5e-3 rad in contact). (4) v_s is a regularisation, not a stick model: :data:`SLIP_SPEED`
(1e-8 m/s) is 1/200 of the rms speed at which the contact point slides in the onset scene's
contacts (2.1e-6 m/s: the probe and the contact's ringing in the 1.56 and 2.53 kHz modes turn
the tip), so the law is Coulomb's wherever it slides. Order of magnitude, micro preset, k = 5
N/m: F_n up to ~18 µN, so at μ = 0.5 |T| up to ~9 µN, a moment ρT ≈ 2e-10 N·m on the tip.
Measured with this stepper on the onset scene's drive (1 Hz whisk, 420 Hz probe, lead-in,
linear wall c = 1.5e-4 N·s/m at 0.1–0.9 of the whisking amplitude, no noise): the contact
intervals are unchanged (the touching flags identical), u changes by at most 3–18 nm at μ = 0.5
(0.6–4 nm at μ = 0.1), and the current in the probe band (300–550 Hz) by 0.10–0.82 nA rms over
the contacts at μ = 0.5 (21–165 pA at μ = 0.1; larger at near walls, where F_n is larger): 1–7
% of the probe current there (11 nA), 100–800× the scene's 1 pA current noise. The friction
damps the probe's motion in contact: a Coulomb describing function adds to Re Zm, as the
texture's does (physics.md §11).

Stepping (:func:`simulate_contact`): the linear part is stepped exactly in the free tip's
eigenbasis, as in :mod:`wtml.physics.friction`, but the force is held first-order over the step
(linear from ``F_k`` to ``F_{k+1}``: trapezoidal in F, second order) and ``F_{k+1}`` is solved
implicitly: the state at k+1 is linear in ``F_{k+1}`` (the step's exact response to a unit
force ramp), so with the static correction ``u = φb·q - a_r F + β_r E`` the penetration and
its rate at k+1 are ``δ = A_u + B_u F`` and ``δ' = A_v + B_v F`` (``B_u, B_v < 0``; the
residual's rate ``-a_r F'`` taken as the step's slope of F) and ``F = f(δ, δ')`` is one scalar
equation per record, solved by Newton's method safeguarded by a bracket (``[0, f(A_u, A_v)]``:
the residual ``F - f`` rises monotonically). Never explicit feedback (§9). With friction the
sliding velocity at k+1 is linear in (F, T) too, ``v_c = A_x + B_x F + C_x T`` (``C_x > 0``),
and T is held first-order over the step like F: for each F the scalar ``T + μ F tanh(v_c/v_s)
= 0`` (rising in T) is solved, and F by Newton's method on ``F - f(δ(F, T(F)), δ'(F, T(F)))``
from the frictionless answer, safeguarded by a bracket: both forces implicit, at every step. A
record with μ = 0 takes the frictionless arithmetic exactly.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from wtml.cores import available_cores
from wtml.physics.stepping import eigenbasis, record_blocks
from wtml.physics.validation import check_range

LAWS = ("linear", "power", "hunt_crossley", "mount_hertz")
"""The contact laws, in the order of their codes (0 to 3)."""

LINEAR, POWER, HUNT_CROSSLEY, MOUNT_HERTZ = range(4)

CONTACT_OUTPUTS = ("slide", "friction")
"""What the contact stepper records beside :data:`~wtml.physics.modal.OUTPUTS`: the contact
point's sliding velocity along the wall ``v_c`` (m/s, along +x, away from the clamp) and the
friction force on the tip ``T`` (N, along +x)."""

SLIP_SPEED = 1e-8
"""The default regularisation v_s of sign(v) in the wall's friction, m/s (see the module's
notes: the contact point slides at ~2e-6 m/s rms in the onset scene's contacts)."""


def law_codes(law) -> np.ndarray:
    """Law names (from :data:`LAWS`) or codes as int64 codes; ValueError naming the allowed."""
    arr = np.atleast_1d(np.asarray(law))
    if arr.dtype.kind in "US":
        bad = sorted(set(arr.tolist()) - set(LAWS))
        if bad:
            raise ValueError(f"law: unknown {bad}; choose from {list(LAWS)}")
        return np.array([LAWS.index(x) for x in arr.tolist()], np.int64)
    check_range("law", arr, 0, len(LAWS) - 1)
    if np.any(arr != np.round(arr)):
        raise ValueError(f"law: codes are integers 0 to {len(LAWS) - 1} ({list(LAWS)})")
    return arr.astype(np.int64)


def hertz_constant(k_ref, delta_ref, k_mount) -> np.ndarray:
    """K_h (N/m^1.5) of a Hertz contact in series with a mount of stiffness ``k_mount`` (N/m)
    whose combined tangent at the penetration ``delta_ref`` (m) is ``k_ref`` (N/m).

    With the Hertz part's penetration x at δ_ref, its tangent compliance is ``(2/3) x / F``
    and ``F = k_m (δ_ref - x)``, so ``1/k_ref = 1/k_m + (2/3) x / (k_m (δ_ref - x))``:
    ``x = 1.5 r δ_ref / (1 + 1.5 r)`` with ``r = k_m/k_ref - 1``, and ``K_h = F / x^1.5``.
    """
    k_ref, delta_ref, k_m = (np.asarray(a, float) for a in (k_ref, delta_ref, k_mount))
    r = k_m / k_ref - 1
    x = 1.5 * r * delta_ref / (1 + 1.5 * r)
    return k_m * (delta_ref - x) / x**1.5


class ContactWall:
    """A wall at the tip with a smooth contact law, for a batch of B records (per-record
    parameters of shape ``(B,)``; scalars broadcast).

    Args:
        gap: g, m, shape ``(B,)`` or ``(B, n_steps)`` (a wall that moves: g at each sample).
        law: names from :data:`LAWS` or their codes.
        k_ref: tangent stiffness at ``delta_ref``, N/m (> 0); the linear law's k.
        delta_ref: reference penetration, m (> 0, <= 1 mm).
        n: the power law's and Hunt–Crossley's exponent, in [1, 1.5].
        alpha: Hunt–Crossley's damping, s/m, in [0, 100].
        k_mount: the mount's stiffness, N/m (``mount_hertz`` records: > k_ref).
        damping: the linear law's c, N·s/m (>= 0, finite).
        friction: μ of the tangential (Coulomb) friction along the wall, in [0, 2]; 0: none.
        slip_speed: v_s, m/s, in (0, 1]: the regularisation ``tanh(v/v_s)`` of sign(v).
        offset: ρ, m, in [0, 1 mm]: the contact point's distance from the whisker's axis (half
            its thickness); required where ``friction > 0``.
    """

    implicit = True

    def __init__(self, gap, law, k_ref, delta_ref=1e-6, n=1.0, alpha=0.0, k_mount=np.inf,
                 damping=0.0, friction=0.0, slip_speed=SLIP_SPEED, offset=None) -> None:
        g = np.asarray(gap, float)
        g = g[:, None] if g.ndim == 1 else np.atleast_2d(g)
        if g.ndim != 2 or not np.all(np.isfinite(g)):
            raise ValueError(f"gap: finite, shape (B,) or (B, n_steps) in m; got shape "
                             f"{np.shape(gap)}")
        self.gap = np.ascontiguousarray(g)
        size = len(g)

        def batch(name, value, lo, hi, unit, **kw):
            arr = np.broadcast_to(np.asarray(value, float), (size,)).copy()
            return check_range(name, arr, lo, hi, unit=unit, **kw)

        self.law = np.broadcast_to(law_codes(law), (size,)).copy()
        self.k_ref = batch("k_ref", k_ref, 0.0, 1e9, "N/m", low_open=True)
        self.delta_ref = batch("delta_ref", delta_ref, 0.0, 1e-3, "m", low_open=True)
        self.n = batch("n", n, 1.0, 1.5, "")
        self.alpha = batch("alpha", alpha, 0.0, 100.0, "s/m")
        self.damping = batch("damping", damping, 0.0, np.inf, "N·s/m", high_open=True)
        self.k_mount = np.broadcast_to(np.asarray(k_mount, float), (size,)).copy()
        self.friction = batch("friction", friction, 0.0, 2.0, "")
        self.slip_speed = batch("slip_speed", slip_speed, 0.0, 1.0, "m/s", low_open=True)
        if offset is None and np.any(self.friction > 0):
            raise ValueError("offset: the contact point's distance from the whisker's axis (half "
                             "its thickness), m, is needed with friction > 0")
        self.offset = batch("offset", 0.0 if offset is None else offset, 0.0, 1e-3, "m")
        mount = self.law == MOUNT_HERTZ
        if np.any(mount):
            check_range("k_mount", self.k_mount[mount] / self.k_ref[mount], 1.0, np.inf,
                        unit="× k_ref", low_open=True, high_open=True)

    @property
    def batch(self) -> int:
        return len(self.gap)

    @property
    def coefficient(self) -> np.ndarray:
        """Each record's K: k_ref (linear), ``k_ref δ_ref^(1-n)/n`` (power, Hunt–Crossley,
        N/m^n) or K_h (mount_hertz, N/m^1.5), ``(B,)``."""
        k = np.where(self.law == LINEAR, self.k_ref,
                     self.k_ref * self.delta_ref ** (1 - self.n) / self.n)
        mount = self.law == MOUNT_HERTZ
        k[mount] = hertz_constant(self.k_ref[mount], self.delta_ref[mount],
                                  self.k_mount[mount])
        return k

    def force(self, delta, rate=0.0) -> np.ndarray:
        """F (N, >= 0) at penetration ``delta`` (m) and its rate ``rate`` (m/s), each
        ``(B,)`` or ``(B, ...)``."""
        d = np.asarray(delta, float)
        ex = (slice(None),) + (None,) * max(0, d.ndim - 1)
        r = np.broadcast_to(np.asarray(rate, float), d.shape)
        k, n, a, c = (x[ex] for x in (self.coefficient, self.n, self.alpha, self.damping))
        law = self.law[ex]
        dp = np.maximum(d, 0.0)
        power = k * dp**np.where(law == LINEAR, 1.0, n)
        f = np.where(law == LINEAR, k * dp + c * r,
                     np.where(law == HUNT_CROSSLEY, power * (1 + a * r), power))
        f = np.broadcast_to(f, d.shape).copy()
        mount = self.law == MOUNT_HERTZ
        f[mount] = _series(dp[mount], k[mount], self.k_mount[ex][mount])
        return np.where(d > 0, np.maximum(f, 0.0), 0.0)


def _series(delta, k_h, k_m) -> np.ndarray:
    """F of the mount in series with Hertz at penetration δ >= 0: ``δ = F/k_m + (F/K_h)^(2/3)``
    with ``F = K_h s³``: ``(K_h/k_m) s³ + s² = δ``, convex in s, Newton from ``s = √δ``."""
    delta, k_h, k_m = np.broadcast_arrays(*(np.asarray(x, float) for x in (delta, k_h, k_m)))
    s = np.sqrt(delta)
    a = k_h / k_m
    for _ in range(100):
        step = np.where(s > 0, (a * s**3 + s**2 - delta) / np.where(s > 0, 3 * a * s**2
                                                                    + 2 * s, 1.0), 0.0)
        s = s - step
        if np.all(np.abs(step) <= 1e-15 * np.abs(s)):
            break
    return k_h * s**3


def simulate_contact(model, e, de_step, de_out, dt: float, load: ContactWall, coupling_scale,
                     cols: np.ndarray, dtype, threads: int | None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Step ``model`` (a :class:`~wtml.physics.modal.ModalTransducer`) from rest with the
    contact wall ``load``; the arguments as prepared by its ``simulate`` (``cols`` index into
    :data:`~wtml.physics.modal.OUTPUTS` + :data:`CONTACT_OUTPUTS`). Returns the recorded
    outputs ``(len(cols), B, n_steps)`` and ``contact`` (``F > 0``, bool ``(B, n_steps)``)."""

    bsz, n_steps = load.batch, e.shape[1]
    if load.gap.shape[1] not in (1, n_steps):
        raise ValueError(f"gap: shape (B,) or (B, {n_steps}) for the drive's {n_steps} "
                         f"samples, got {load.gap.shape}")
    sliding = bool(np.any(load.friction > 0)) or bool(np.any(np.asarray(cols) >= 4))
    if sliding and model.tip_slope is None:
        raise ValueError("friction: the wall's friction acts through the modes' tip slope; "
                         "make the model with ModalTransducer.from_beam (tip_slope is None)")
    zero = np.zeros(bsz)
    lam, gain, out, feed, to_modal, to_state = eigenbasis(
        model.step_matrices(dt, zero, zero, coupling_scale))
    # the force enters q'' as -φb F, as E enters as φθ E: a model whose coupling is -φb gives,
    # in its E and Ė columns, the step's exact response to F held and to F's slope; the
    # friction T enters as ψ T with ψ = -ρ φs (one model with coupling φs, scaled per record)
    ns = 2 * model.n_modes + 1
    pushed = type(model)(model.omega_n, model.zeta, model.tip, -model.tip)
    held, ramp = np.moveaxis(to_modal @ pushed.step_matrices(dt, zero, zero)[:, :ns, ns:ns + 2],
                             2, 0)
    rho = load.offset
    if sliding:
        turned = type(model)(model.omega_n, model.zeta, model.tip, model.tip_slope)
        t_held, t_ramp = np.moveaxis(
            -rho[:, None, None] * (to_modal @ turned.step_matrices(dt, zero, zero)[:, :ns,
                                                                                 ns:ns + 2]),
            2, 0)
        row = np.zeros(ns)
        row[model.n_modes:2 * model.n_modes] = model.tip_slope  # θ' = φs·q'
        slide = -rho[:, None] * (row @ to_state)  # v_c = -ρ θ' in the eigenbasis, (B, m)
    else:
        t_held = t_ramp = slide = np.zeros_like(held)

    def parts(a: np.ndarray) -> np.ndarray:  # (B, ...) complex -> (2, ..., B)
        return np.ascontiguousarray(np.moveaxis(np.stack([a.real, a.imag]), 1, -1))

    gains = np.concatenate([gain[..., :2], held[..., None], ramp[..., None], t_held[..., None],
                            t_ramp[..., None]], 2)
    out = np.concatenate([out, slide[:, None]], 1)
    lam, gains, out = parts(lam), parts(np.moveaxis(gains, 2, 1)), parts(out)
    feed = np.ascontiguousarray(np.moveaxis(feed[..., [0, 3]], 0, -1))  # on [E, Ė_out]
    a_r, b_r, _ = model.residual
    b_r = b_r * np.broadcast_to(np.asarray(coupling_scale, float), (bsz,))
    rate = (np.diff(load.gap, axis=1, prepend=load.gap[:, :1]) / dt if load.gap.shape[1] > 1
            else np.zeros_like(load.gap))
    params = (load.law, load.coefficient, load.n, load.alpha, load.damping, load.k_mount,
              load.friction, load.slip_speed)
    values = np.empty((len(cols), bsz, n_steps), dtype)
    contact = np.empty((bsz, n_steps), bool)
    blocks = record_blocks(bsz, threads)

    def step(b: slice) -> None:
        own = b if len(e) > 1 else slice(0, 1)
        _step_contact(lam[..., b].copy(), gains[..., b].copy(), out[..., b].copy(),
                      feed[..., b].copy(), *(np.ascontiguousarray(x[own])
                                             for x in (e, de_step, de_out)),
                      load.gap[b], rate[b], *(p[b].copy() for p in params), a_r,
                      b_r[b].copy(), dt, sliding, cols, values[:, b], contact[b])

    with ThreadPoolExecutor(min(len(blocks), threads or available_cores())) as pool:
        list(pool.map(step, blocks))
    return values, contact


@njit(cache=True)
def _law(law, d, r, k, n, alpha, c):
    """``f(δ, δ')`` of the laws given explicitly (not mount_hertz) and its partial
    derivatives in δ and δ'."""
    if d <= 0.0:
        return 0.0, 0.0, 0.0
    if law == LINEAR:
        f = k * d + c * r
        if f <= 0.0:
            return 0.0, 0.0, 0.0
        return f, k, c
    p = k * d**n
    if law == POWER:
        return p, n * p / d, 0.0
    h = 1.0 + alpha * r
    if h <= 0.0:
        return 0.0, 0.0, 0.0
    return p * h, n * p * h / d, p * alpha


@njit(cache=True)
def _solve(law, au, bu, av, bv, k, n, alpha, c, k_m):
    """The force F >= 0 with ``F = f(A_u + B_u F, A_v + B_v F)`` (``B_u, B_v <= 0``).

    Explicit laws: ``R(F) = F - f`` rises (at least at slope 1), ``R(0) = -f(A_u, A_v)``; Newton
    from 0, kept inside the bracket ``[0, f(A_u, A_v)]`` and bisecting when it leaves it (where
    f jumps, at a damped linear law's touch, it ends at the jump: the tip held at δ = 0).
    mount_hertz: with ``F = K_h s³``, ``K_h (1/k_m - B_u) s³ + s² = A_u`` is convex and rising
    in s >= 0: Newton from ``s = √A_u`` descends onto the root.
    """
    if law == MOUNT_HERTZ:
        if au <= 0.0:
            return 0.0
        a = k * (1.0 / k_m - bu)
        s = np.sqrt(au)
        for _ in range(100):
            step = (a * s**3 + s * s - au) / (3.0 * a * s * s + 2.0 * s)
            s -= step
            if abs(step) <= 1e-15 * s:
                break
        return k * s**3
    top = _law(law, au, av, k, n, alpha, c)[0]
    if top <= 0.0:
        return 0.0
    lo, hi, x = 0.0, top, 0.0
    for _ in range(200):
        f, fd, fr = _law(law, au + bu * x, av + bv * x, k, n, alpha, c)
        res = x - f
        if res > 0.0:
            hi = x
        elif res < 0.0:
            lo = x
        else:
            return x
        nxt = x - res / (1.0 - fd * bu - fr * bv)
        if not lo < nxt < hi:  # Newton left the bracket (or sits on its end): bisect
            nxt = 0.5 * (lo + hi)
        if abs(nxt - x) <= 1e-15 * top or hi - lo <= 1e-15 * top:
            return nxt
        x = nxt
    return x


@njit(cache=True)
def _tangential(fn, a0, cx, mu, vs):
    """The friction T (N, on the tip along +x) with ``T = -μ F_n tanh((a0 + c_x T)/v_s)``
    (``a0`` the contact point's sliding velocity at the step's end without this step's T,
    ``c_x >= 0`` its mobility to T), and its partial derivatives in a0 and in F_n.

    ``R(T) = T + μ F_n tanh(·)`` rises at slope >= 1, ``R(-μF_n) <= 0 <= R(μF_n)``: Newton
    from the explicit value, kept inside the bracket and bisecting when it leaves it.
    """
    cap = mu * fn
    if cap <= 0.0:
        return 0.0, 0.0, -mu * np.tanh(a0 / vs)
    lo, hi = -cap, cap
    x = -cap * np.tanh(a0 / vs)
    for _ in range(200):
        th = np.tanh((a0 + cx * x) / vs)
        res = x + cap * th
        slope = 1.0 + cap * (1.0 - th * th) * cx / vs
        if res > 0.0:
            hi = x
        elif res < 0.0:
            lo = x
        else:
            break
        nxt = x - res / slope
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - x) <= 1e-15 * cap or hi - lo <= 1e-15 * cap:
            x = nxt
            break
        x = nxt
    th = np.tanh((a0 + cx * x) / vs)
    sech2 = 1.0 - th * th
    den = 1.0 + cap * sech2 * cx / vs
    return x, -cap * sech2 / vs / den, -mu * th / den


@njit(cache=True)
def _residual(law, fn, au, bu, cu, av, bv, cv, ax, bx, cx, k, n, alpha, c, k_m, mu, vs):
    """The normal force's residual at ``F_n = fn`` with its friction ``T(F_n)`` solved
    (:func:`_tangential`), its derivative in F_n, and T: ``F_n - f(δ, δ')`` (explicit laws,
    N) or ``δ_s(F_n) - δ`` with ``δ_s = F/k_m + (F/K_h)^(2/3)`` (mount_hertz, m); δ, δ' and
    the sliding velocity linear in (F_n, T) with the coefficients given."""
    t, dt_da, dt_dn = _tangential(fn, ax + bx * fn, cx, mu, vs)
    dt_df = dt_da * bx + dt_dn
    d, r = au + bu * fn + cu * t, av + bv * fn + cv * t
    dd, dr = bu + cu * dt_df, bv + cv * dt_df
    if law == MOUNT_HERTZ:
        if fn <= 0.0:
            return -d, np.inf, t
        return (fn / k_m + (fn / k) ** (2.0 / 3.0) - d,
                1.0 / k_m + (2.0 / 3.0) * fn ** (-1.0 / 3.0) * k ** (-2.0 / 3.0) - dd, t)
    f, fd, fr = _law(law, d, r, k, n, alpha, c)
    return fn - f, 1.0 - fd * dd - fr * dr, t


@njit(cache=True)
def _solve_friction(law, au, bu, cu, av, bv, cv, ax, bx, cx, k, n, alpha, c, k_m, mu, vs):
    """The normal force F_n >= 0 and the friction T solved together at the step's end: δ, δ'
    and the contact point's sliding velocity are linear in (F_n, T); ``F_n = f(δ, δ')`` and
    ``T = -μ F_n tanh(v_c / v_s)``. F_n by Newton's method on :func:`_residual` (T solved
    inside it for each F_n), from the frictionless answer, safeguarded by a bracket: the
    residual is negative at 0 (where T = 0, as without friction) and the bracket's upper end
    is found by doubling. Returns ``(F_n, T)``."""
    x = _solve(law, au, bu, av, bv, k, n, alpha, c, k_m)
    if x <= 0.0:
        return 0.0, 0.0
    scale = x
    lo, hi = 0.0, -1.0
    res, der, t = _residual(law, x, au, bu, cu, av, bv, cv, ax, bx, cx, k, n, alpha, c, k_m,
                            mu, vs)
    if res > 0.0:
        hi = x
    elif res < 0.0:
        lo = x
        probe = x
        for _ in range(200):
            probe = 2.0 * probe
            if _residual(law, probe, au, bu, cu, av, bv, cv, ax, bx, cx, k, n, alpha, c, k_m,
                         mu, vs)[0] >= 0.0:
                hi = probe
                break
            lo = probe
    else:
        return x, t
    for _ in range(200):
        nxt = x - res / der if der > 0.0 and np.isfinite(der) else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - x) <= 1e-15 * scale or hi - lo <= 1e-15 * scale:
            x = nxt
            break
        x = nxt
        res, der, t = _residual(law, x, au, bu, cu, av, bv, cv, ax, bx, cx, k, n, alpha, c,
                                k_m, mu, vs)
        if res > 0.0:
            hi = x
        elif res < 0.0:
            lo = x
        else:
            break
    res, der, t = _residual(law, x, au, bu, cu, av, bv, cv, ax, bx, cx, k, n, alpha, c, k_m,
                            mu, vs)
    return x, t


@njit(cache=True, nogil=True)
def _step_contact(lam, gain, out, feed, e, de_step, de_out, gap, gap_rate, law, coef, expo,
                  alpha, damping, k_mount, mu, slip, a_r, b_r, dt, sliding, cols, values,
                  contact):
    """The contact stepper for a block of B records side by side, in the free tip's
    eigenbasis: ``lam`` (2, m, B), ``gain`` (2, 6, m, B) on ``[E, Ė, F held, F's slope,
    T held, T's slope]``, ``out`` (2, 5, m, B) and ``feed`` (4, 2, B) on ``[E, Ė_out]`` for
    ``(u_m, u_m', ·, i, v_c)`` without the force's residual terms.

    The state ``w`` is kept as its prediction without the current step's forces; each
    sample's F (and, with friction, T) solves :func:`_solve` (:func:`_solve_friction`) with
    ``δ = u - g``, ``δ' = u' - g'`` and the sliding velocity ``v_c`` linear in them (at k = 0,
    from rest, F enters only through the residual and T not at all), then ``w`` takes their
    share and the outputs are recorded: ``u = u_m - a_r F``, ``u' = u_m' - a_r Ḟ``,
    ``i = i_m - β_r Ḟ`` with Ḟ the step's slope ``(F_k - F_{k-1})/dt``; ``v_c`` and T. A
    record with μ = 0 takes exactly the frictionless arithmetic.

    Args:
        gap, gap_rate: g (m) and g' (m/s), ``(B, 1)`` or ``(B, n_steps)``.
        law, coef, expo, alpha, damping, k_mount, mu, slip: per record, ``(B,)``
            (:class:`ContactWall`).
        sliding: whether ``v_c`` is needed (friction or its outputs recorded).
        values: written, ``(len(cols), B, n_steps)``; contact: written, bool ``(B, n_steps)``.
    """
    m, bsz = lam.shape[1], lam.shape[2]
    w = np.zeros((2, m, bsz))
    last = np.zeros(bsz)
    last_t = np.zeros(bsz)
    bu_step, bv_step = np.empty(bsz), np.empty(bsz)
    cu_step, cv_step = np.zeros(bsz), np.zeros(bsz)
    bx_step, cx_step = np.zeros(bsz), np.zeros(bsz)
    for b in range(bsz):  # u_m and u_m' at the step's end per unit F there (ramped from 0)
        su, sv = 0.0, 0.0
        for j in range(m):
            su += (out[0, 0, j, b] * gain[0, 3, j, b] - out[1, 0, j, b] * gain[1, 3, j, b])
            sv += (out[0, 1, j, b] * gain[0, 3, j, b] - out[1, 1, j, b] * gain[1, 3, j, b])
        bu_step[b], bv_step[b] = su / dt, sv / dt
        if sliding:  # and per unit T; v_c per unit F and T
            for j in range(m):
                cu_step[b] += (out[0, 0, j, b] * gain[0, 5, j, b]
                               - out[1, 0, j, b] * gain[1, 5, j, b]) / dt
                cv_step[b] += (out[0, 1, j, b] * gain[0, 5, j, b]
                               - out[1, 1, j, b] * gain[1, 5, j, b]) / dt
                bx_step[b] += (out[0, 4, j, b] * gain[0, 3, j, b]
                               - out[1, 4, j, b] * gain[1, 3, j, b]) / dt
                cx_step[b] += (out[0, 4, j, b] * gain[0, 5, j, b]
                               - out[1, 4, j, b] * gain[1, 5, j, b]) / dt
    y = np.zeros(6)
    n_gap = gap.shape[1]
    for k in range(e.shape[1]):
        kg = min(k, n_gap - 1)
        share = 1.0 if k > 0 else 0.0
        for b in range(bsz):
            src = b if e.shape[0] > 1 else 0
            ek, ok = e[src, k], de_out[src, k]
            for r in (0, 1, 3):
                acc = feed[r, 0, b] * ek + feed[r, 1, b] * ok
                for j in range(m):
                    acc += out[0, r, j, b] * w[0, j, b] - out[1, r, j, b] * w[1, j, b]
                y[r] = acc
            ax = 0.0
            if sliding:
                for j in range(m):
                    ax += out[0, 4, j, b] * w[0, j, b] - out[1, 4, j, b] * w[1, j, b]
            bu = share * bu_step[b] - a_r
            bv = share * bv_step[b] - a_r / dt
            au = y[0] - gap[b, kg]
            av = y[1] + a_r * last[b] / dt - gap_rate[b, kg]
            t = 0.0
            if mu[b] > 0.0:
                cu, cv = share * cu_step[b], share * cv_step[b]
                bx, cx = share * bx_step[b], share * cx_step[b]
                f, t = _solve_friction(law[b], au, bu, cu, av, bv, cv, ax, bx, cx, coef[b],
                                       expo[b], alpha[b], damping[b], k_mount[b], mu[b],
                                       slip[b])
            else:
                f = _solve(law[b], au, bu, av, bv, coef[b], expo[b], alpha[b], damping[b],
                           k_mount[b])
            if k > 0:
                for j in range(m):
                    w[0, j, b] += gain[0, 3, j, b] / dt * f
                    w[1, j, b] += gain[1, 3, j, b] / dt * f
                if mu[b] > 0.0:
                    for j in range(m):
                        w[0, j, b] += gain[0, 5, j, b] / dt * t
                        w[1, j, b] += gain[1, 5, j, b] / dt * t
            slope = (f - last[b]) / dt
            if mu[b] > 0.0:
                y[0] = au + bu * f + cu * t + gap[b, kg]
                y[1] = av + bv * f + cv * t + gap_rate[b, kg]
            else:
                y[0] = au + bu * f + gap[b, kg]
                y[1] = av + bv * f + gap_rate[b, kg]
            y[2] = f
            cur = feed[3, 0, b] * ek + feed[3, 1, b] * ok - b_r[b] * slope
            for j in range(m):
                cur += out[0, 3, j, b] * w[0, j, b] - out[1, 3, j, b] * w[1, j, b]
            y[3] = cur
            if sliding:
                vc = 0.0
                for j in range(m):
                    vc += out[0, 4, j, b] * w[0, j, b] - out[1, 4, j, b] * w[1, j, b]
                y[4] = vc
            y[5] = t
            for c in range(len(cols)):
                values[c, b, k] = y[cols[c]]
            contact[b, k] = f > 0.0
            last[b] = f
            last_t[b] = t
        for j in range(m):
            for b in range(bsz):
                src = b if e.shape[0] > 1 else 0
                ek, dk, fk, tk = e[src, k], de_step[src, k], last[b], last_t[b]
                re, im = w[0, j, b], w[1, j, b]
                w[0, j, b] = (lam[0, j, b] * re - lam[1, j, b] * im + gain[0, 0, j, b] * ek
                              + gain[0, 1, j, b] * dk + (gain[0, 2, j, b] - gain[0, 3, j, b]
                                                         / dt) * fk)
                w[1, j, b] = (lam[0, j, b] * im + lam[1, j, b] * re + gain[1, 0, j, b] * ek
                              + gain[1, 1, j, b] * dk + (gain[1, 2, j, b] - gain[1, 3, j, b]
                                                         / dt) * fk)
                if tk != 0.0:
                    w[0, j, b] += (gain[0, 4, j, b] - gain[0, 5, j, b] / dt) * tk
                    w[1, j, b] += (gain[1, 4, j, b] - gain[1, 5, j, b] / dt) * tk
