"""The wall's own motion, read from the whisk band of the transducer's current.

A still wall gives a record whose whisk cycles repeat: the drive, the contact and so the
current are the same in each. An object moving with the floor (physics.md §12: 0.8 µm rms at
5–20 Hz on a lab floor) is met at another place in each look, and the onset decoder's answer
is then off by where the wall happened to be when the tip met it, something no look at the
wall alone can tell when its looks happen to agree. The current tells it. In contact, at
frequencies far below the first mode, the transducer moves the charge ``Q = C E + HUE(0) F``
(reciprocity: the charge per tip force at a fixed voltage is the tip's displacement per volt;
equivalently ``1/t11 = HUE(0) k_tip`` at low frequency), and the tip force is
``F = k_s (x_free − g − x_b)``, with ``k_s`` the tip's stiffness under voltage drive in series
with the wall's (:func:`series_stiffness`) and ``x_b`` the wall's motion. Where the tip
touches in two whisk cycles, the difference of their charges at the same whisk phase holds
the wall's motion alone (the drive's share cancels):

    ΔQ(τ) = −HUE(0) k_s (x_b(τ + T_w) − x_b(τ)).

:class:`WallMotion` integrates each frame's current level (the frame's whisk-band current,
mains lines removed) less the level one whisk cycle before into ΔQ, takes a straight line
through the frames where neither cycle touches (a still wall's ΔQ there is noise; the line
takes the slow drift of that noise), and returns ``rms(ΔQ − line) / (√2 HUE(0) k_s)`` over
the frames where either touches: the rms of the wall's motion (m), ``x_b`` a whisk cycle
apart being two samples of it (a floor's 5–20 Hz forgets itself within a cycle). Measured on
the main job's scene (1 Dec, 96 records a level, the looks' decoder's contact
probabilities): a still wall reads 2–10 nm (5th–95th percentile; the current's noise), a
wall moving 0.1 µm rms reads 1.12× its true rms at the median, 0.8 µm 1.14× (before the
mains period's average; the scene's hum, 50 Hz on a 1 Hz whisk, cancels between cycles).

The onset net's answer pools four looks at the wall (each whisk cycle's approach and
retreat), each meeting the wall where it then was, so the wall's motion adds
``rms / √looks`` to its σ (:meth:`~wtml.decoders.onset.OnsetNet.forward`). ``k_s`` is the
scene's nominal (the wall's stiffness is a nuisance the net does not output): over the
trained walls (3–8 N/m and their laws' tangents) the true ``k_s`` spreads about ±20 % around
it, which sets how well the motion is read, not whether a still wall reads zero.

The same running sums serve a stream (:meth:`WallMotion.running`, the state carried from
chunk to chunk) and a whole record (one chunk from a zero state), so both graphs compute it
alike.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

LOW_HZ = 0.5
"""Hz: the frequency at which the tip's stiffness under voltage drive is read from the
nominal device's T (``k_tip = |jω t12 / t11|``; within 1e-5 of its static value on the
shipped presets, whose first mode is at 400 Hz)."""

SUMS = 12
"""The running sums after the two buffers: ΔQ so far, then over the frames where neither
cycle touches ``n, Σt, Σt², Σq, Σtq`` and where either does ``n, Σt, Σt², Σq, Σq², Σtq``."""


def frame_means(x: torch.Tensor, period: int) -> torch.Tensor:
    """Each frame's mean of ``x`` ``(batch, n_samples)``: ``(batch, n_samples // period)``
    (a frame is ``period`` samples, one probe period; the probe's own cycles average out)."""
    n = x.shape[1] // period
    return x[:, :n * period].unflatten(1, (n, period)).mean(-1)


def mains_taps(mains_frames: float) -> list[float]:
    """The weights of an average over one mains period of ``mains_frames`` frames (whole or
    not: the last tap weighs the fraction), newest first, summing to 1; ``[1.0]`` for 0 (no
    mains)."""
    if mains_frames <= 1:
        return [1.0]
    whole = int(math.floor(mains_frames))
    taps = [1.0] * whole + ([mains_frames - whole] if mains_frames > whole + 1e-9 else [])
    return [w / mains_frames for w in taps]


def series_stiffness(scene) -> float:
    """``k_s`` (N/m) of :mod:`this module <wtml.decoders.wall_motion>`: the nominal device's
    tip stiffness under voltage drive (at :data:`LOW_HZ`) in series with the scene's wall at
    the geometric mean of its stiffness range."""
    w = 2 * np.pi * LOW_HZ
    t = scene.transducer().transduction_matrix(np.array([w]))[0]
    k_tip = float(abs(1j * w * t[0, 1] / t[0, 0]))
    k_wall = float(np.sqrt(np.prod(scene.wall.stiffness)))
    return k_tip * k_wall / (k_tip + k_wall)


class WallMotion(nn.Module):
    """Frames' mean currents and contact probabilities -> the wall's rms motion (m), from the
    whisk cycles' difference (module docstring).

    Args:
        cycle_frames: frames per whisk cycle (whole or not: a fractional lag is read by
            cubic interpolation between the four frames about it; a line between two would
            leave (2π/lag)²/8 of the whisk's own current, some 3 pA a frame of its 40 nA at
            262.5 frames a cycle, a false motion of ~0.1 µm once summed over a contact).
        frame_s: s per frame (one probe period).
        stiffness: ``k_s``, N/m (:func:`series_stiffness`).
        mains_frames: frames per mains period (the probe over the mains frequency; 0: no
            average, :func:`mains_taps`).

    Shapes: ``level`` (A), ``prob`` ``(batch, n)`` (this chunk's frames), ``hue0``
    ``(batch,)`` m/V, ``start`` ``(batch,)`` the chunk's first frame's index in its record,
    ``state`` ``(batch, state_size)`` (zeros before a record's first frame) -> the rms
    ``(batch,)`` m over the record so far, and the state after the chunk.
    """

    def __init__(self, cycle_frames: float, frame_s: float, stiffness: float,
                 mains_frames: float = 0.0) -> None:
        super().__init__()
        if not (cycle_frames >= 1 and frame_s > 0 and stiffness > 0 and mains_frames >= 0):
            raise ValueError(f"WallMotion: cycle_frames >= 1, frame_s and stiffness > 0, "
                             f"mains_frames >= 0, got {cycle_frames}, {frame_s}, {stiffness}, "
                             f"{mains_frames}")
        self.lag = float(cycle_frames)
        self.whole = int(math.floor(self.lag))
        self.part = self.lag - self.whole  # the lag's fraction of a frame
        # the first frame with a cycle before it (and, for a fractional lag, the four frames
        # about it), and the frames carried for the lag
        self.first = self.whole + (2 if self.part > 0 else 0)
        self.keep = self.whole + 2
        u = self.part  # Lagrange's weights at lags whole - 1, whole, whole + 1, whole + 2
        self.weights = [-u * (u - 1) * (u - 2) / 6, (u + 1) * (u - 1) * (u - 2) / 2,
                        -(u + 1) * u * (u - 2) / 2, (u + 1) * u * (u - 1) / 6]
        self.taps = mains_taps(mains_frames)
        self.extra = len(self.taps) - 1  # and for the mains period's average
        # µm of ΔQ / (HUE(0) k_s) per A·frame of current, times HUE(0) (m/V, per record)
        self.per_level = 1e6 * frame_s / stiffness

    @property
    def state_size(self) -> int:
        """The carried means (for the lag and the average) and probabilities (for the lag),
        and :data:`SUMS`."""
        return 2 * self.keep + self.extra + SUMS

    def initial_state(self, batch: int) -> torch.Tensor:
        return torch.zeros(batch, self.state_size)

    def forward(self, level: torch.Tensor, prob: torch.Tensor, hue0: torch.Tensor
                ) -> torch.Tensor:
        """A whole record's rms (m), ``(batch,)``."""
        start = torch.zeros_like(hue0)
        # zeros of the batch's size taken from a tensor: the tracer keeps the batch dynamic
        state = start[:, None].expand(-1, self.state_size)
        return self.running(level, prob, hue0, start, state)[0]

    def at_lag(self, x: torch.Tensor, n: int, back: int) -> torch.Tensor:
        """The frames ``back`` before each of the last ``n`` of ``x`` ``(batch, m)``."""
        end = x.shape[1] - back
        return x[:, end - n:end]

    def before(self, x: torch.Tensor, n: int) -> torch.Tensor:
        """Each of the last ``n`` frames of ``x`` ``(batch, keep + n)`` one lag before (cubic
        between the four frames about it for a fractional lag), ``(batch, n)``."""
        if self.part == 0:
            return self.at_lag(x, n, self.whole)
        return sum(w * self.at_lag(x, n, self.whole + k)
                   for k, w in zip((-1, 0, 1, 2), self.weights, strict=True))

    def running(self, level: torch.Tensor, prob: torch.Tensor, hue0: torch.Tensor,
                start: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The rms (m) over the record so far and the state after this chunk (class
        docstring)."""
        n, keep, extra = level.shape[1], self.keep, self.extra
        levels = torch.cat([state[:, :keep + extra], level], 1)
        probs = torch.cat([state[:, keep + extra:2 * keep + extra], prob], 1)
        sums = state[:, 2 * keep + extra:]
        # the cycle difference on this chunk's frames and the `extra` before them
        frames = start[:, None] + torch.arange(-extra, n, dtype=level.dtype)
        valid = (frames >= self.first).to(level.dtype)
        diff = (levels[:, keep:] - self.before(levels, n + extra)) * valid
        step = sum(w * diff[:, extra - k:extra - k + n] for k, w in enumerate(self.taps))
        p_before = self.at_lag(probs, n, self.whole)
        if self.part > 0:  # touching at either frame about the lag
            p_before = torch.maximum(p_before, self.at_lag(probs, n, self.whole + 1))
        valid = valid[:, extra:]
        touch = ((prob > 0.5) | (p_before > 0.5)).to(level.dtype) * valid
        free = valid - touch
        # µm of the wall's motion a whisk cycle apart, from the second cycle on
        q = sums[:, :1] + torch.cumsum(step, 1) * (self.per_level / hue0[:, None])
        t = frames[:, extra:] / self.lag  # whisk cycles: O(1) for float32's sums
        add = torch.stack([free.sum(1), (free * t).sum(1), (free * t * t).sum(1),
                           (free * q).sum(1), (free * t * q).sum(1),
                           touch.sum(1), (touch * t).sum(1), (touch * t * t).sum(1),
                           (touch * q).sum(1), (touch * q * q).sum(1),
                           (touch * t * q).sum(1)], 1)
        sums = torch.cat([q[:, -1:], sums[:, 1:] + add], 1)
        after = torch.cat([levels[:, levels.shape[1] - keep - extra:],
                           probs[:, probs.shape[1] - keep:], sums], 1)
        return self.rms(sums), after

    @staticmethod
    def rms(sums: torch.Tensor) -> torch.Tensor:
        """The wall's rms motion (m) from the running sums ``(batch, SUMS)``: ΔQ's rms about
        the line through the free frames (a level line with fewer than two free frames, 0
        with no touching frame), over √2."""
        _, n0, t0, tt0, q0, tq0, n1, t1, tt1, q1, qq1, tq1 = sums.unbind(1)
        det = n0 * tt0 - t0 * t0
        fitted = (n0 >= 2) & (det > 1e-6 * n0 * n0)
        safe = torch.where(fitted, det, torch.ones_like(det))
        slope = torch.where(fitted, (n0 * tq0 - t0 * q0) / safe, torch.zeros_like(det))
        mean = torch.where(n0 > 0, q0 / n0.clamp_min(1.0), torch.zeros_like(det))
        level = torch.where(fitted, (tt0 * q0 - t0 * tq0) / safe, mean)
        resid = (qq1 - 2 * level * q1 - 2 * slope * tq1 + level * level * n1
                 + 2 * level * slope * t1 + slope * slope * tt1)
        return 1e-6 * torch.sqrt(resid.clamp_min(0.0) / n1.clamp_min(1.0) / 2)
