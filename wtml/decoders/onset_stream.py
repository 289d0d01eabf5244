"""The onset decoder for a device that streams: fixed-size chunks in, its state carried out.

:class:`StreamingOnset` runs a trained :class:`~wtml.decoders.onset.OnsetNet` chunk by chunk.
Everything the offline graph computes over a whole record is causal or a running sum:

- the probe frames are per frame (a chunk holds whole probe periods);
- u_L's and Zm's steps need the previous frame's u_L and Zm;
- each causal convolution needs its last ``(kernel - 1) dilation`` inputs;
- each softmax pooling is a running (max, Σ exp, Σ exp·x[, Σ exp·σ²]), merged chunk by chunk;
  g's also per look at the wall (each whisk cycle's approach and retreat: Σ exp, Σ exp·x),
  for the looks' agreement (:func:`~wtml.decoders.onset.touch_spread`);
- the domain gate's record summary is running sums, a maximum and a minimum;
- the mains lines' estimate (:class:`~wtml.decoders.onset.MainsLines`) is running sums;
- a contact's confirmation (:func:`~wtml.decoders.onset.confirm`) needs the last few touches
  and whether one was confirmed before;
- the wall's own motion (:class:`~wtml.decoders.wall_motion.WallMotion`) needs the last
  whisk cycle's current levels and contact probabilities, and its running sums.

So after the last chunk of a record, the running ``gap``, ``sigma``, levels and domain score
(the gate's, the looks' agreement over its limit and the wall's motion's share of σ over
its limit) equal the offline graph's (to float32 rounding), and the per-frame contact
probabilities of the chunks, concatenated, equal the offline ones. The per-frame detachment
margins use the level known so far (the offline graph uses the record's final level).

The state is one flat float32 tensor per record (``(batch, state_size)``); a device keeps it
between calls and starts each record from zeros (the frame count in it is 0 before the first
chunk, which tells the running maxima and the steps that nothing came before).
"""

from __future__ import annotations

import torch
from torch import nn

from wtml.decoders.domain import DomainGate
from wtml.decoders.onset import (
    CONFIRM_FRAMES,
    MOTION_LIMIT,
    CausalConv,
    OnsetNet,
    RecordSummary,
    answer,
    confirm,
)
from wtml.decoders.wall_motion import frame_means

POOLS = (("vote", "est", "log_sd", 0), ("vote_off", "est_off", None, 4))
"""The two softmax poolings: vote, estimate, (for g) the log std, and where their running
sums start in the pooled state (13 values: the poolings' (max, Σ exp, Σ exp·x[, Σ exp·σ²]),
then the top contact probability, the frame count, Σ(|E_H| − level), max u_L, min u_L,
Σ(|I_H| − level), the levels the gate's training means); after them g's Σ exp of each look
(:meth:`~wtml.decoders.onset.OnsetNet.look_of`), then its Σ exp·x of each, on the same running
max."""


class StreamingOnset(nn.Module):
    """``(e, i, t_re, t_im, hue0, state) -> (contact, detach_margin, touch, gap, sigma,
    next_state, in_domain, domain_score)`` for chunks of ``chunk_frames`` probe periods; the
    device's calibration ``t_re, t_im, hue0`` as the offline graph takes it
    (:data:`~wtml.decoders.onset.CALIBRATION`), the same in every chunk of a record.

    Args:
        net: a trained onset net.
        gate: its domain gate (features: :class:`~wtml.decoders.onset.RecordSummary`).
        chunk_frames: probe periods per chunk (the chunk is ``chunk_frames × period``
            samples of each channel).
        check_limit: the limit of the looks' agreement
            (:func:`~wtml.decoders.onset.touch_spread`, σ), as the offline graph's (the
            wall's own motion's share of σ is held to
            :data:`~wtml.decoders.onset.MOTION_LIMIT`, as there).

    Shapes: ``e``, ``i`` ``(batch, chunk_samples)`` V and A; ``state`` ``(batch,
    state_size)``; ``contact``, the margin and ``touch`` ``(batch, chunk_frames)``; the rest
    ``(batch,)``.
    """

    def __init__(self, net: OnsetNet, gate: DomainGate, chunk_frames: int = 1, *,
                 check_limit: float) -> None:
        super().__init__()
        if chunk_frames < 1:
            raise ValueError(f"chunk_frames must be >= 1, got {chunk_frames}")
        if not check_limit > 0:
            raise ValueError(f"check_limit must be > 0, got {check_limit!r}")
        self.net, self.gate, self.chunk_frames = net, gate, int(chunk_frames)
        self.register_buffer("check_limit", torch.tensor(float(check_limit)))
        self.convs = [m for m in net.body if isinstance(m, CausalConv)]
        self.sizes = ([3] + [m.conv.in_channels * m.pad for m in self.convs]
                      + [net.frames.state_size, CONFIRM_FRAMES + 1, 13, 2 * net.looks,
                         0 if net.motion is None else net.motion.state_size])
        self.state_size = sum(self.sizes)
        # the running sums of |E_H| and |I_H| add each frame's deviation from the training
        # records' mean level, so float32 rounding scales with the deviations, not the level
        # (whitened by the gate, the level's rounding over a record was ~2e-3 of the score)
        self.register_buffer("level_e", gate.mean[0].detach().clone() / 1e3)
        self.register_buffer("level_i", 10 ** gate.mean[2].detach().clone())

    @property
    def chunk_samples(self) -> int:
        return self.chunk_frames * self.net.frames.period

    def initial_state(self, batch: int) -> torch.Tensor:
        """The state before a record's first chunk: zeros, ``(batch, state_size)``."""
        return torch.zeros(batch, self.state_size)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor,
                hue0: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, ...]:
        parts = torch.split(state, self.sizes, 1)
        prev, buffers, mains, confirmed, pool, looks, moved = (
            parts[0], parts[1:-5], parts[-5], parts[-4], parts[-3], parts[-2], parts[-1])
        net = self.net
        # (batch, chunk_frames, 5), the mains lines' running sums from the frames so far
        f, mains = net.frames.running(e, i, t_re, t_im, hue0, pool[:, 8], mains)
        first = pool[:, 8] == 0  # no frame before this chunk

        def running(op, old, new):
            return torch.where(first, new, op(old, new))

        prev = torch.where(first[:, None, None], f[:, :1, :3], prev[:, None])
        per_volt = net.reach_per_volt(t_re, t_im)
        step = net.scaled(net.steps(f, prev), per_volt)
        x = net.inputs(f, step)
        carried = []
        for layer in net.body:
            if isinstance(layer, CausalConv):
                past = buffers[len(carried)].unflatten(1, (layer.conv.in_channels, layer.pad))
                full = torch.cat([past, x], -1)
                carried.append(full[..., full.shape[-1] - layer.pad:].flatten(1))
                x = layer.conv(full)
            else:
                x = layer(x)
        p = net.outputs(net.head(x), f, step, per_volt)
        pooled, merged = [], []
        for vote, est, log_sd, at in POOLS:
            run = pool[:, at:at + (4 if log_sd else 3)]
            m = running(torch.maximum, run[:, 0], p[vote].amax(-1))
            w = torch.exp(p[vote] - m[:, None])
            scale = torch.where(first, 0.0, torch.exp(run[:, 0] - m))
            s0 = run[:, 1] * scale + w.sum(-1)
            s1 = run[:, 2] * scale + (w * p[est]).sum(-1)
            mean = s1 / s0
            sums = [m, s0, s1]
            if log_sd:
                s2 = run[:, 3] * scale + (w * torch.exp(2 * p[log_sd])).sum(-1)
                sums.append(s2)
                pooled += [mean, torch.sqrt(s2 / s0) * net.amp]
                # per look (each whisk cycle's approach and retreat), on the same running max
                at_frame = pool[:, 8:9] + torch.arange(w.shape[1], dtype=w.dtype)
                onehot = net.look_of(at_frame)  # (batch, chunk_frames, looks)
                c0 = (looks[:, :net.looks] * scale[:, None]
                      + (w[..., None] * onehot).sum(1))
                c1 = (looks[:, net.looks:] * scale[:, None]
                      + ((w * p[est])[..., None] * onehot).sum(1))
                share, look_sums = c0 / s0[:, None], c1 / s0[:, None]
            else:
                pooled.append(mean)
            merged += sums
        prob, past, seen = confirm(torch.sigmoid(p["contact"]), p["touch"],
                                   confirmed[:, :CONFIRM_FRAMES], confirmed[:, CONFIRM_FRAMES])
        top = torch.maximum(pool[:, 7], prob.amax(-1))
        count = pool[:, 8] + f.shape[1]
        sum_e = pool[:, 9] + (f[..., 3] - self.level_e).sum(-1)
        u_max = running(torch.maximum, pool[:, 10], f[..., 0].amax(-1))
        u_min = running(torch.minimum, pool[:, 11], f[..., 0].amin(-1))
        sum_i = pool[:, 12] + (f[..., 4] - self.level_i).sum(-1)
        summary = torch.cat([torch.stack([1e3 * (self.level_e + sum_e / count),
                                          1e6 * (u_max - u_min) / 2,
                                          torch.log10(self.level_i + sum_i / count)], -1),
                             RecordSummary.device(t_re, t_im, hue0)], -1)
        # this chunk's margin uses the level so far and the contact seen so far
        gap, sd, off_margin = answer(*pooled[:2], top, p, pooled[2])
        spread = net.agreement(share, look_sums, gap, sd)
        if net.motion is None:
            motion = torch.zeros_like(hue0)
        else:
            motion, moved = net.motion.running(frame_means(i, net.frames.period), prob, hue0,
                                               pool[:, 8], moved)
        sd, part = net.widened(gap, sd, motion)
        score = torch.maximum(torch.maximum(self.gate.score(summary),
                                            spread / self.check_limit), part / MOTION_LIMIT)
        inside = (score <= 1.0) & self.gate.outputs_in_range((gap, sd))
        sd = torch.where(inside, sd, torch.full_like(sd, float("nan")))
        new_pool = torch.stack(merged + [top, count, sum_e, u_max, u_min, sum_i], -1)
        carried += ([] if mains is None else [mains]) + [past, seen[:, None]]
        next_state = torch.cat([f[:, -1, :3], *carried, new_pool, c0, c1, moved], 1)
        return prob, off_margin, p["touch"], gap, sd, next_state, inside, score
