"""Friction at the tip of the time-domain transducer: a whisker sweeping sandpaper
(physics.md §11, thesis §4.5).

The tip slides along the surface in its whisking direction u, pressed against it with a normal
force N at a contact angle θ (between the whisker and the surface's normal plane; the surface
carries ``N cos θ``). The force the transducer applies to the surface, along u::

    F = μ N cos θ tanh(v / v_s) + c v + F_asp(t)

- Coulomb friction regularised over ``v_s`` (its fundamental is in phase with V: the
  describing function ``4 μ N cos θ / (π |V|)`` adds to Re Zm);
- a viscous part ``c v``;
- asperities: grains at random positions ``x_j`` along the path (spacing drawn around the mean
  grain size d), each an impulse ``J_j`` (N·s) along the motion when the tip crosses it, so that
  they arrive at the rate |v|/d. :func:`grains` draws them with ``J = a N cos θ d / v_a``
  (``v_a`` = 1 m/s): their mean force is ``a N cos θ |v| / v_a``, a drag that grows with d
  through ``a(d)``.

The force is a smooth function of the state, evaluated once per step from the tip's velocity
and position at the sample and held over the step at its mid-step extrapolation (the linear
part is stepped exactly, in the free tip's eigenbasis). That is stable where
``(μ N / v_s + c) dt Σφb²`` stays well below 1; the
tests show halving the step moves the fundamental phasors by less than a scene's noise.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from wtml.physics.validation import check_range

REFERENCE_SPEED = 1.0
"""v_a, m/s: the speed at which an asperity's impulse J equals ``a N cos θ d / v_a``."""


class Friction:
    """Sliding friction at the tip for a batch of B records (arrays of shape ``(B,)``).

    Args:
        mu: Coulomb coefficient μ (>= 0).
        normal_force: N, N (>= 0).
        angle: contact angle θ, rad, in [0, π/2).
        slip_speed: v_s, m/s (> 0), the regularisation of sign(v).
        viscous: c, N·s/m (>= 0).
        positions: grain positions along the path from the tip's rest position, m, sorted,
            shape ``(B, G)`` (pad with +inf); None: no asperities.
        impulses: each grain's impulse, N·s (>= 0), shape ``(B, G)``.
    """

    smooth = True

    def __init__(self, mu, normal_force, angle=0.0, slip_speed=0.01, viscous=0.0,
                 positions=None, impulses=None) -> None:
        self.mu = check_range("mu", np.atleast_1d(np.asarray(mu, float)), 0.0, 10.0).copy()
        size = len(self.mu)

        def batch(name, value, lo, hi, unit, **kw):
            arr = np.broadcast_to(np.asarray(value, float), (size,)).copy()
            return check_range(name, arr, lo, hi, unit=unit, **kw)

        self.normal_force = batch("normal_force", normal_force, 0.0, 10.0, "N")
        self.angle = batch("angle", angle, 0.0, np.pi / 2, "rad", high_open=True)
        self.slip_speed = batch("slip_speed", slip_speed, 0.0, 10.0, "m/s", low_open=True)
        self.viscous = batch("viscous", viscous, 0.0, 10.0, "N·s/m")
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
        """μ N cos θ, N, ``(B,)``: the sliding force's magnitude."""
        return self.mu * self.normal_force * np.cos(self.angle)

    def force(self, velocity) -> np.ndarray:
        """The smooth part ``μ N cos θ tanh(v/v_s) + c v``, N, for v (m/s) of shape ``(B, ...)``."""
        v = np.asarray(velocity, float)
        ex = (slice(None),) + (None,) * (v.ndim - 1)
        return (self.coulomb[ex] * np.tanh(v / self.slip_speed[ex]) + self.viscous[ex] * v)


def describing_function(coulomb, speed) -> np.ndarray:
    """Re Zm of pure Coulomb friction at the fundamental, ``4 μ N cos θ / (π |V|)``, N·s/m.

    Args:
        coulomb: μ N cos θ, N.  speed: |V|, the velocity's amplitude, m/s (> 0).
    """
    speed = check_range("speed", speed, 0.0, np.inf, unit="m/s", low_open=True)
    return 4 * np.asarray(coulomb, float) / (np.pi * speed)


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
    from wtml.physics.modal import _blocks, _eigenbasis, available_cores

    bsz, n_steps = load.batch, e.shape[1]
    lam, gain, out, feed, _, _ = _eigenbasis(model.step_matrices(
        dt, np.zeros(bsz), np.zeros(bsz), coupling_scale, force_input=True))

    def parts(a: np.ndarray) -> np.ndarray:  # (B, ...) complex -> (2, ..., B)
        return np.ascontiguousarray(np.moveaxis(np.stack([a.real, a.imag]), 1, -1))

    lam, gain, out = parts(lam), parts(np.moveaxis(gain[..., :3], 2, 1)), parts(out)
    feed = np.ascontiguousarray(np.moveaxis(feed[..., [0, 3, 2]], 0, -1))  # on [E, Ė_out, F]
    values = np.empty((len(cols), bsz, n_steps), dtype)
    start = np.array([np.searchsorted(p, 0.0) for p in load.positions], np.int64)
    blocks = _blocks(bsz, threads)

    def step(b: slice) -> None:
        own = b if len(e) > 1 else slice(0, 1)
        _step_friction(lam[..., b].copy(), gain[..., b].copy(), out[..., b].copy(),
                       feed[..., b].copy(), *(np.ascontiguousarray(a[own])
                                              for a in (e, de_step, de_out)),
                       load.coulomb[b].copy(), load.slip_speed[b].copy(),
                       load.viscous[b].copy(), load.positions[b], load.impulses[b],
                       start[b].copy(), dt, cols, values[:, b])

    with ThreadPoolExecutor(min(len(blocks), threads or available_cores())) as pool:
        list(pool.map(step, blocks))
    return values


@njit(cache=True, nogil=True)
def _step_friction(lam, gain, out, feed, e, de_step, de_out, coulomb, slip, viscous,
                   positions, impulses, start, dt, cols, values):
    """The friction stepper for a block of B records side by side, in the free tip's
    eigenbasis: ``lam`` (2, m, B), ``gain`` (2, 3, m, B) on ``[E, Ė, F]``, ``out`` (2, 4, m, B)
    and ``feed`` (4, 3, B) on ``[E, Ė_out, F]`` for the outputs (u, v, F, i). At each sample
    the force is evaluated from v and from the grains the tip crosses during the coming step
    (by ``u + v dt``, u without the force's own residual part: the impulse lands in the step
    that holds the crossing, not one step late) and recorded; its smooth part, extrapolated to the
    middle of the step from the last two samples, and the grains' impulse are held over the step
    (second order in dt for the smooth part).

    Args:
        positions, impulses: ``(B, G)`` grains; start: the grains below u = 0, ``(B,)``.
        values: written, ``(len(cols), B, n_steps)``.
    """
    m, bsz = lam.shape[1], lam.shape[2]
    w = np.zeros((2, m, bsz))
    ptr = start.copy()
    force = np.zeros(bsz)
    smooth = np.zeros(bsz)  # the smooth part at the last sample
    y = np.zeros(4)
    n_grain = positions.shape[1]
    for k in range(e.shape[1]):
        for b in range(bsz):
            src = b if e.shape[0] > 1 else 0
            ek, ok = e[src, k], de_out[src, k]
            for r in range(4):
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
            now = coulomb[b] * np.tanh(v / slip[b]) + viscous[b] * v
            y[2] = now + kick / dt
            y[0] += feed[0, 2, b] * y[2]
            # held over the step: the smooth part extrapolated to mid-step (second order)
            force[b] = (1.5 * now - 0.5 * smooth[b] if k > 0 else now) + kick / dt
            smooth[b] = now
            for c in range(len(cols)):
                values[c, b, k] = y[cols[c]]
        for j in range(m):
            for b in range(bsz):
                src = b if e.shape[0] > 1 else 0
                ek, dk, fk = e[src, k], de_step[src, k], force[b]
                re, im = w[0, j, b], w[1, j, b]
                w[0, j, b] = (lam[0, j, b] * re - lam[1, j, b] * im + gain[0, 0, j, b] * ek
                              + gain[0, 1, j, b] * dk + gain[0, 2, j, b] * fk)
                w[1, j, b] = (lam[0, j, b] * im + lam[1, j, b] * re + gain[1, 0, j, b] * ek
                              + gain[1, 1, j, b] * dk + gain[1, 2, j, b] * fk)
