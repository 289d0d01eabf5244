"""The contact-onset decoder: wall location and contact intervals from e(t), i(t).

The graph takes the raw records and computes its own features per probe period (the frames:
64 samples at the defaults), so a device feeds it what its ADC gives:

1. :class:`ProbeFrames`: per frame, a least-squares fit of ``[1, t, t², cos ωH t, sin ωH t]``
   to e and to i, relative to the frame's first sample for float32 (the polynomial soaks up
   the whisking ramp, which would otherwise leak into the probe's phasor): the whisking
   position ``u_L = HUE(0) e_L`` and the probe phasors
   ``E_H, I_H``, then ``Zm = (t22 E_H - t12 I_H)/(t11 I_H - t21 E_H)`` through the
   calibrated T at the probe frequency (real arithmetic, exportable). T at the probe and
   HUE(0) are the user's calibration of their own device: inputs of the graph (``t_re``,
   ``t_im`` ``(batch, 4)``, ``hue0`` ``(batch,)`` m/V; :data:`CALIBRATION`), never constants
   of the preset, so the decoder maps each device through its own T. Before that, the mains
   lines (hum at 50 or 60 Hz and harmonics) are taken out of each frame's fit, estimated
   causally from the fits' residuals (:class:`MainsLines`), and Zm uses the probe voltage's
   running mean over the record (the drive's, unchanged by a contact).
2. A causal temporal convolution over the frames (dilated, so it sees ~60 frames back: the
   400 Hz mode rings for ~40 ms), fed the normalised frames, u_L's step and Zm's step from
   the frame before (compressed by asinh on the scale of free whisking's frame-to-frame
   jitter; the step scaled to the nominal device's noise, :meth:`OnsetNet.scaled`). Per frame:
   the contact logit, and for two quantities a vote weight and the frame's estimate (relative
   to the free tip's reach on the probe peaks, ``u_L + |u_H|``, below): the wall's location g
   (with a log std) and the *detachment level* (below). Because it is causal, the streaming
   form (:class:`StreamingOnset`, fed chunks, its state carried) gives the offline answer.
3. Each quantity is pooled over the frames by softmax weights, ``g = Σ_t w_t (u_L(t) +
   |u_H(t)| + δ_t)``: each frame near an edge says where the wall is relative to the tip's
   reach, which accounts for the tip touching on the probe's peaks before u_L reaches g (§10)
   with each device's own probe amplitude |u_H| (|t12| at the probe spreads 0.5-1.4x over the
   trained devices). g's variance is the same weighted mean of the frames' variances.
4. Timing. The first touch, on a probe peak, shows in its own frame as a step of Zm from the frame
   before (4e-6 N·s/m and more, where free whisking's frames differ by ~1e-7 on a quiet acquisition
   and ~6e-7 on the bench-top one): the output ``touch`` is that step's size over a threshold fitted
   to the training data's acquisition (:func:`touch_threshold`: between free whisking's steps just
   before each onset and the first touches'). A record reports contacts only once one is confirmed
   by a touch (:func:`confirm`). A contact is a run of frames whose contact probability passes 0.5
   (labels: the frames that hold a touching instant) and it starts on the first frame, from a few
   before the run up to its first such frame, whose ``touch`` is >= 1
   (:func:`wtml.runtime.contacts.contacts_from`). (Taking the onset from the trajectory instead, the
   first frame whose reach passes a learned level, needs that level to ~10 nm: the frames' reach
   brackets are 0.09-0.19 µm wide and the true level is often within 10 nm of an edge; the main
   job's small training got it to 34 nm, and every miss was one probe period early or late.) A first
   touch that only grazes its probe peak (a few nm) steps Zm no more than free whisking does, and
   the onset is then called one frame late. A contact ends on the last frame whose reach on the
   probe peaks, ``u_L + |u_H|`` (``|u_H| = |E_H| / (ωH |t12|)``, the calibrated free-tip response,
   known per frame to ~1e-12 m from e alone), passes the detachment level, which the net estimates;
   the output ``detach_margin`` is reach minus that level per frame (m).

Inputs: ``e`` (V), ``i`` (A) ``(batch, n_samples)`` and the calibration ``t_re, t_im,
hue0``. The whisking amplitude of the nominal device (``amp``) is the unit of the net's
offsets only (a device's own amplitude differs by a few %, its offsets by as little).

Outputs (each ``(batch,)`` unless said): ``gap`` and ``sigma`` (m, NaN in a record without
contact: :func:`answer` decides wall and contacts together), ``contact`` (``(batch,
n_frames)``, probability per frame), ``detach_margin`` (m, ``(batch, n_frames)``; -1 m in a
record without contact), ``touch`` (``(batch, n_frames)``), ``wall_motion`` (the wall's
own motion, read from the whisk cycles' currents, as a share of the net's σ:
:meth:`OnsetNet.widened`, :mod:`wtml.decoders.wall_motion`; σ holds that motion too) and
``touch_spread`` (how far the whisk cycles' approaches and retreats locate the wall apart, in
σ: :func:`touch_spread`). The exported graphs fold the last two into the domain score, over
:data:`MOTION_LIMIT` and over a limit fitted on fresh records.
Intervals come from these by :func:`wtml.runtime.contacts.contacts_from` plus the
onset/detachment phases in the metadata (where in its frame a contact starts and ends,
fitted on training labels).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as fn

from wtml.decoders.base import ConfigError, DecoderModule, check_positive
from wtml.decoders.domain import RESOLUTION
from wtml.decoders.layers import ZmFromEI
from wtml.decoders.wall_motion import WallMotion, frame_means, series_stiffness

CALIBRATION = ("t_re", "t_im", "hue0")
"""The graph's inputs after ``e, i``: the user's calibrated T at the probe frequency, real and
imaginary parts ``(batch, 4)`` as ``T.reshape(4)`` (t11, t12, t21, t22), and HUE(0) (m/V,
``(batch,)``)."""

FRAME_CLIP = 30.0
"""Normalised frame features are held within ±this many training std before the convolution.
A contact's Zm is ~10 std; a frame in which a contact switches can read a nearly vanishing
tip velocity and |Zm| ~1000 std (met over the device spread: 0.31 N·s/m), which drove the
main job's training to NaN."""

SELF_CHECKS = ("wall_motion", "touch_spread")
"""The onset net's last outputs, in order: checks of its own answer, which the exported graphs
fold into the domain score (:class:`~wtml.decoders.domain.Gated`'s ``checks``)."""

MOTION_LIMIT = 1.0
"""The largest share of the net's σ that the wall's own motion may take in an answer in
domain (:meth:`OnsetNet.widened`): beyond it the answer is mostly where the wall happened to
be at the looks, and σ mostly the motion read through the scene's nominal wall stiffness
(±20 % over the trained walls), so the graph flags it rather than widen σ further."""

LEVEL_SCALE = 0.001
"""The detachment level's loss is log cosh of its error in units of this fraction of the
whisking amplitude (13 nm at the defaults: quadratic below, linear above), so the loss stays
steep down to the scale of its brackets' edges."""


def frame_basis(period: int, full: bool = False) -> np.ndarray:
    """Rows that take ``(e_L, cos-coefficient, sin-coefficient)`` out of one probe period of
    ``period`` samples by least squares on ``[1, t, t², cos, sin]`` (t centred), shape
    ``(3, period)`` (``full``: all five coefficients' rows and the basis, ``(5, period)`` and
    ``(period, 5)``)."""
    t = np.arange(period) - (period - 1) / 2
    w = 2 * np.pi / period
    n = np.arange(period)
    basis = np.stack([np.ones(period), t / period, (t / period) ** 2,
                      np.cos(w * n), np.sin(w * n)], 1)
    pinv = np.linalg.pinv(basis)
    return (pinv, basis) if full else pinv[[0, 3, 4]]


HUM_RIDGE = 0.1
"""The mains estimate's ridge, per line in units of that line's information in one frame (the
diagonal of one frame's normal matrix): it keeps the first frames' estimate near zero (the
fundamental is nearly a parabola over a frame, so one frame hardly tells it from the whisk),
and shrinks each line by ``HUM_RIDGE / (n + HUM_RIDGE)`` after n frames."""


def asinh(x: torch.Tensor) -> torch.Tensor:
    """``asinh(x)`` from ops the TorchScript exporter has (it has no Asinh): with x's sign,
    of ``a = |x|``, its series to a⁹ below 0.1 (truncation 2e-13) and
    ``log(a + sqrt(a² + 1))`` above, within 1.2e-7 of torch's asinh in float32; the slope at
    0 is 1, as asinh's, and |x| is taken as at most 1e18 (asinh 42.1; x² would overflow
    float32 past 1.8e19)."""
    def positive(a: torch.Tensor) -> torch.Tensor:
        a = a.clamp(0.0, 1e18)  # each side's slope passes at 0 (abs would stop it)
        s = a.clamp(max=0.1)  # the branch not taken stays finite, and so do their slopes
        s2 = s * s
        series = s * (1.0 - s2 * (1.0 / 6.0 - s2 * (3.0 / 40.0 - s2 * (15.0 / 336.0
                                                                      - s2 * 105.0 / 3456.0))))
        return torch.where(a < 0.1, series, torch.log(a + torch.sqrt(a * a + 1.0)))

    return torch.where(x < 0, -positive(-x), positive(x))


class MainsLines(nn.Module):
    """The mains lines' (hum's) share of each probe frame's fit, estimated causally.

    Over one frame the fit ``[1, t, t², cos ωH t, sin ωH t]`` takes the whisking ramp and the
    probe exactly, and leaves in its residual what else the frame holds; a line at
    ``h f_m`` (hum) leaves a known shape there and leaks a known amount into the fitted
    (level, cos, sin). So the hum's amplitudes (per harmonic, cos and sin at absolute time)
    are a least-squares fit to the residuals of every frame so far: the normal equations'
    right side is a running sum (carried by a stream). The estimate at frame k uses frames
    ``<= k`` only, so the offline graph and the streaming one agree, and it is subtracted from
    each frame's fit as the leak it makes.

    Ungated (the voltage channel, which a contact does not change), every frame counts and the
    normal matrix depends only on the frame count: its inverse is a table (frames beyond it:
    the last entry scaled by the count, the matrix growing linearly once the lines' phases have
    gone round). Gated (the current channel), only the frames a caller marks free count (a
    contact's current leaves residuals of its own, which biased the lines' estimate on every
    frame after the first contact: free whisking's Zm steps before a second-cycle onset rose
    from 1.5e-6 to 6.4e-6 N·s/m), and the matrix is taken as its average over the lines'
    phases times the count (block diagonal: exact over whole turns of the phases, 42 frames at
    50 Hz and a 420 Hz probe), with the ridge fading over the first turn.

    Args:
        period: samples per frame (probe period).
        frame_hz: frames per second (the probe frequency).
        mains_hz: the mains frequency (50 or 60 Hz).
        harmonics: how many lines, ``h = 1 .. harmonics`` (each below the probe).
        table: frames in the inverse table (a record's frames at the scene's length).
        gated: estimate from the frames marked free only (see above).
    """

    def __init__(self, period: int, frame_hz: float, mains_hz: float, harmonics: int,
                 table: int, gated: bool = False) -> None:
        super().__init__()
        if harmonics < 1 or harmonics * mains_hz >= frame_hz:
            raise ConfigError(f"mains lines: {harmonics} harmonics of {mains_hz:g} Hz must "
                              f"lie below the probe's {frame_hz:g} Hz")
        pinv, basis = frame_basis(period, full=True)
        q = np.eye(period) - basis @ pinv  # the frame fit's residual operator
        tau = np.arange(period)
        omega = 2 * np.pi * mains_hz * np.arange(1, harmonics + 1) / (frame_hz * period)
        g0 = np.concatenate([np.stack([np.cos(o * tau), np.sin(o * tau)], 1) for o in omega], 1)
        m = g0.T @ q @ g0
        self.register_buffer("residual", torch.tensor(q @ g0, dtype=torch.float32))
        self.register_buffer("leak", torch.tensor((pinv[[0, 3, 4]] @ g0).T,
                                                  dtype=torch.float32))
        cycles = mains_hz * np.arange(1, harmonics + 1) / frame_hz  # per frame
        self.register_buffer("cycles", torch.tensor(cycles, dtype=torch.float32))
        k = np.arange(table)[:, None] * cycles
        c, s = np.cos(2 * np.pi * k), np.sin(2 * np.pi * k)
        rot = np.zeros((table, 2 * harmonics, 2 * harmonics))
        for h in range(harmonics):  # local (cos, sin) rows from absolute (cos, sin) columns
            rot[:, 2 * h, 2 * h], rot[:, 2 * h, 2 * h + 1] = c[:, h], s[:, h]
            rot[:, 2 * h + 1, 2 * h], rot[:, 2 * h + 1, 2 * h + 1] = -s[:, h], c[:, h]
        self.gated = bool(gated)
        diag = np.repeat([np.trace(m[2 * h:2 * h + 2, 2 * h:2 * h + 2]) / 2
                          for h in range(harmonics)], 2)
        if self.gated:
            self.register_buffer("diag", torch.tensor(diag, dtype=torch.float32))
            self.turn = float(np.ceil(5 * frame_hz / mains_hz))  # frames for the ridge to fade
        else:
            gram = (np.cumsum(np.einsum("kai,ab,kbj->kij", rot, m, rot), 0)
                    + HUM_RIDGE * np.diag(diag))
            self.register_buffer("inverse", torch.tensor(np.linalg.inv(gram),
                                                         dtype=torch.float32))
        self.lines = 2 * harmonics
        self.size = self.lines + int(self.gated)  # gated: the count of free frames too

    def rotation(self, k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """cos and sin of each line's phase at the start of frames ``k`` (float), ``(..., H)``."""
        a = 2 * np.pi * torch.remainder(k[..., None] * self.cycles, 1.0)
        return torch.cos(a), torch.sin(a)

    def forward(self, d: torch.Tensor, start: torch.Tensor, sums: torch.Tensor,
                free: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Frames ``d`` ``(batch, n, period)`` (less their first sample), the index of the
        first (``(batch,)`` float), the running sums before it ``(batch, size)`` and, gated,
        which frames count (``free``, ``(batch, n)`` 0/1) -> the lines' leak into each frame's
        (level, cos, sin) ``(batch, n, 3)`` and the sums after the last frame."""
        n = d.shape[1]
        k = start[:, None] + torch.arange(n, dtype=d.dtype)[None]  # (batch, n)
        c, s = self.rotation(k)
        p = (d @ self.residual).unflatten(-1, (-1, 2))  # local (cos, sin) per line
        v = torch.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], -1)
        v = v.flatten(2)
        if self.gated:
            v = v * free[..., None]
        total = sums[:, None, :self.lines] + torch.cumsum(v, 1)  # (batch, n, 2H)
        if self.gated:
            count = sums[:, None, self.lines] + torch.cumsum(free, 1)  # (batch, n)
            # the ridge fades over the first turn of the phases, where the matrix is not yet
            # its phase average
            ridge = HUM_RIDGE * (1 + torch.relu(self.turn - count))
            theta = total / ((count + ridge)[..., None] * self.diag)
            after = torch.cat([total[:, -1], count[:, -1:]], 1)
        else:
            at = torch.clamp(k, max=float(len(self.inverse) - 1))
            grow = torch.clamp(len(self.inverse) / (k + 1), max=1.0)
            theta = (self.inverse[at.long()] @ total[..., None])[..., 0] * grow[..., None]
            after = total[:, -1]
        theta = theta.unflatten(-1, (-1, 2))
        local = torch.stack([c * theta[..., 0] + s * theta[..., 1],
                             -s * theta[..., 0] + c * theta[..., 1]], -1)
        return local.flatten(2) @ self.leak, after


class ProbeFrames(nn.Module):
    """``(e, i)`` ``(batch, n_samples)`` and the calibration (:data:`CALIBRATION`) -> frames
    ``(batch, n_frames, 5)``: ``u_L`` (m), ``Re Zm, Im Zm`` (N·s/m), ``|E_H|`` (V), and
    ``|I_H| / (|Y_free| |E_H|)``, the probe current over what the device's free tip draws
    (``Y_free = t22/t12``, from Zm = 0): 1 on free whisking for every device, where
    ``|I_H|`` itself differs between devices by more than a contact changes it.

    Args:
        period: samples per probe period (an integer: the scene's rate is a multiple of the
            probe frequency).
        mains: the mains lines removed from both channels' frames (:class:`MainsLines`,
            one per channel: e's ungated, i's gated), or None. With them, Zm is taken through
            the probe voltage's running mean over the record so far (a running sum a stream
            carries), not each frame's.
        free_below: u_L (m) below which the tip cannot touch (the scene's nearest wall less
            the probe's reach): i's mains lines are estimated on those frames only.
    """

    def __init__(self, period: int, mains: tuple[MainsLines, MainsLines] | None = None,
                 free_below: float = 0.0) -> None:
        super().__init__()
        self.free_below = float(free_below)
        self.period = int(period)
        self.register_buffer("basis", torch.tensor(frame_basis(self.period).T,
                                                   dtype=torch.float32))
        self.zm = ZmFromEI()
        self.mains = None if mains is None else nn.ModuleList(mains)

    @property
    def state_size(self) -> int:
        """The running sums a stream carries: the mains lines' (both channels) and the probe
        voltage's phasor (2)."""
        return 0 if self.mains is None else sum(m.size for m in self.mains) + 2

    def fit(self, x: torch.Tensor, mains: MainsLines | None = None,
            start: torch.Tensor | None = None, sums: torch.Tensor | None = None,
            free: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``(batch, n_samples)`` -> ``(batch, 3, n_frames)``: frame level, cos, sin, less the
        mains lines' leak (``mains``, from frame ``start`` with running ``sums`` and, gated,
        the frames that count, ``free``; see :class:`MainsLines`), and the sums after the last
        frame (None without lines).

        Each frame is fitted relative to its first sample (exact in float32), so rounding
        scales with the signal's change within a frame, not with its level: the whisking
        drive is ~500 times the probe, and a fit on the raw samples loses the probe's
        phasor to float32 rounding (graphs that sum in another order disagree there)."""
        n = x.shape[1] // self.period
        frames = x[:, :n * self.period].unflatten(1, (n, self.period))
        first = frames[..., :1]
        d = frames - first
        fit, after = d @ self.basis, None
        if mains is not None:
            leak, after = mains(d, start, sums, free)
            fit = fit - leak
        fit = fit.transpose(1, 2)
        return (fit + torch.cat([first[..., 0][:, None], torch.zeros_like(fit[:, 1:])], 1),
                after)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor, hue0: torch.Tensor) -> torch.Tensor:
        return self.running(e, i, t_re, t_im, hue0)[0]

    def running(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor, hue0: torch.Tensor, start: torch.Tensor | None = None,
                sums: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The frames of ``(e, i)`` with the calibration ``t_re, t_im, hue0`` (as
        :meth:`forward`) whose first is frame ``start`` of its record (``(batch,)`` float;
        default 0) with the mains lines' running sums before it (``(batch, state_size)``;
        default zeros), and those sums after its last frame (None without mains lines)."""
        s = ZmFromEI.I_SCALE
        if self.mains is None:
            (fe, _), (fi, _) = self.fit(e), self.fit(i * s)
            after = None
        else:
            if start is None:
                start = torch.zeros_like(e[:, 0])
            if sums is None:
                sums = torch.zeros(e.shape[0], self.state_size, dtype=e.dtype)
            half, end = self.mains[0].size, self.state_size - 2
            fe, after_e = self.fit(e, self.mains[0], start, sums[:, :half])
            free = (hue0[:, None] * fe[:, 0] < self.free_below).to(e.dtype)
            fi, after_i = self.fit(i * s, self.mains[1], start, sums[:, half:end], free)
            # the probe voltage is the drive's (a contact does not change it): Zm takes its
            # running mean over the record so far, not each frame's, whose ADC noise made
            # ~40 % of free whisking's Zm steps (median 6.9e-7 -> 5.5e-7 N·s/m)
            total = sums[:, None, end:] + torch.cumsum(fe[:, 1:].transpose(1, 2), 1)
            k = start[:, None] + torch.arange(fe.shape[2], dtype=e.dtype)[None] + 1
            probe = (total / k[..., None]).transpose(1, 2)
            after = torch.cat([after_e, after_i, total[:, -1]], 1)
        # x = c cos + s sin = Re(X e^{jωt}) with X = c - j s
        e_re, e_im, i_re, i_im = fe[:, 1], -fe[:, 2], fi[:, 1], -fi[:, 2]
        # Zm through each record's own T, from the probe voltage's running mean with the
        # mains lines (the drive's), else from each frame's
        pe_re, pe_im = (e_re, e_im) if self.mains is None else (probe[:, 0], -probe[:, 1])
        zm_re, zm_im = self.zm(pe_re, pe_im, i_re, i_im, t_re, t_im)
        y_free = torch.sqrt((t_re[:, 3:] * t_re[:, 3:] + t_im[:, 3:] * t_im[:, 3:])
                            / (t_re[:, 1:2] * t_re[:, 1:2] + t_im[:, 1:2] * t_im[:, 1:2]))
        free = (s * y_free * torch.sqrt(pe_re * pe_re + pe_im * pe_im)).clamp_min(1e-30)  # µA
        return torch.stack([hue0[:, None] * fe[:, 0], zm_re, zm_im,
                            torch.sqrt(e_re * e_re + e_im * e_im),
                            torch.sqrt(i_re * i_re + i_im * i_im) / free], -1), after


class RecordSummary(nn.Module):
    """The domain gate's features of a record, ``(batch, 3 + N_DEVICE)``: probe level |E_H|
    (mV), whisking amplitude of u_L (µm), log10 of the mean probe current relative to the
    free tip's (:class:`ProbeFrames`), then the device as its
    calibration shows it (:meth:`device`)."""

    N_DEVICE = 5
    """The device features (:meth:`device`)."""

    def __init__(self, frames: ProbeFrames) -> None:
        super().__init__()
        self.frames = frames

    @staticmethod
    def device(t_re: torch.Tensor, t_im: torch.Tensor, hue0: torch.Tensor) -> torch.Tensor:
        """HUE(0) (µm/V), Re and Im of t12 and of t21 at the probe, ``(batch, N_DEVICE)``:
        what the gate needs to tell a device outside the trained spread. Not all of T: det T
        = 1 ties its elements, and a direction the training devices never move (their
        covariance's null space) would flag any measured T, whose determinant is 1 only to
        its measurement's precision."""
        return torch.stack([1e6 * hue0, t_re[:, 1], t_im[:, 1], t_re[:, 2], t_im[:, 2]], -1)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor, hue0: torch.Tensor) -> torch.Tensor:
        f = self.frames(e, i, t_re, t_im, hue0)
        u = f[..., 0] * 1e6
        return torch.cat([torch.stack([1e3 * f[..., 3].mean(-1), (u.amax(-1) - u.amin(-1)) / 2,
                                       torch.log10(f[..., 4].mean(-1))], -1),
                          self.device(t_re, t_im, hue0)], -1)


class CausalConv(nn.Module):
    """A causal dilated 1-D convolution: output frame t sees input frames ``<= t``."""

    def __init__(self, c_in: int, c_out: int, kernel: int, dilation: int) -> None:
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.conv = nn.Conv1d(c_in, c_out, kernel, dilation=dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(fn.pad(x, (self.pad, 0)))


class OnsetNet(nn.Module):
    """Frames -> (gap m, sigma m, contact probability per frame, detachment margin per frame
    m, touch per frame, the wall's own motion's share of σ, the whisk cycles' looks' spread
    in σ); see the module docstring.

    Args:
        frames: the feature layer.
        scale: ``(mean, std)`` of the 5 frame features over the training data, ``(2, 5)``.
        zm_step: the scale of Zm's frame-to-frame step (Re, Im; N·s/m), ``(2,)``: its median
            over the training frames, nearly all of free whisking.
        touch_step: the size of Zm's step (N·s/m) that marks a touch (:func:`touch_threshold`).
        amp: the nominal whisking amplitude, m (the offsets' unit).
        probe_omega: ωH, rad/s (the free tip's probe amplitude per probe volt is
            ``1/(ωH |t12|)`` with each record's calibrated t12).
        channels, dilations, kernel: the temporal convolution.
        cycle_frames: frames per whisk cycle (probe periods per whisking period: the
            ratio of the two tones, which need not be whole).
        cycles: whisk cycles in a record (a frame past the last belongs to it).
        wall_stiffness: ``k_s`` (N/m) for reading the wall's own motion from the whisk
            cycles' currents (:mod:`wtml.decoders.wall_motion`; its
            :func:`~wtml.decoders.wall_motion.series_stiffness`); 0: not read (σ the net's
            alone, and the motion's share 0).
        mains_hz: the lab's mains frequency (the motion's read averaged over its period; 0:
            not averaged).
    """

    HEADS = 6
    """Per frame: contact logit; vote, estimate, log std of g; vote, estimate of the
    detachment level."""

    def __init__(self, frames: ProbeFrames, scale: torch.Tensor, zm_step: torch.Tensor,
                 touch_step: float, amp: float, probe_omega: float, channels: int,
                 dilations: tuple[int, ...], *, cycle_frames: float, cycles: int,
                 kernel: int = 3, t12: float = 0.0, wall_stiffness: float = 0.0,
                 mains_hz: float = 0.0) -> None:
        super().__init__()
        if not cycle_frames >= 1 or cycles < 1:
            raise ValueError(f"cycle_frames and cycles must be >= 1, got {cycle_frames}, "
                             f"{cycles}")
        self.cycle_frames, self.cycles = float(cycle_frames), int(cycles)
        # the nominal device's |t12| at the probe (0: steps not rescaled; see :meth:`scaled`)
        self.per_volt_ref = 1.0 / (float(probe_omega) * t12) if t12 > 0 else 0.0
        self.frames = frames
        self.register_buffer("mean", scale[0].float().clone())
        self.register_buffer("std", scale[1].float().clone())
        self.register_buffer("zm_step", zm_step.float().clone())
        self.register_buffer("touch_step", torch.tensor(float(touch_step)))
        self.amp = float(amp)
        self.probe_omega = float(probe_omega)
        layers, c_in = [], 8
        for d in dilations:
            layers += [CausalConv(c_in, channels, kernel, d), nn.GELU()]
            c_in = channels
        self.body = nn.Sequential(*layers)
        self.head = nn.Conv1d(channels, self.HEADS, 1)
        # the wall's own motion (no parameters: a checkpoint's state is the same without it)
        frame_hz = self.probe_omega / (2 * np.pi)
        self.motion = (WallMotion(cycle_frames, 1 / frame_hz, wall_stiffness,
                                  frame_hz / mains_hz if mains_hz > 0 else 0.0)
                       if wall_stiffness > 0 and self.cycles > 1 else None)

    @staticmethod
    def steps(f: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """The step of (u_L m, Re Zm, Im Zm N·s/m) from the frame before, ``(batch, n, 3)``,
        given those of the frame before the first, ``(batch, 1, 3)``."""
        x = torch.cat([previous, f[..., :3]], 1)
        return x[:, 1:] - x[:, :-1]

    def scaled(self, step: torch.Tensor, per_volt: torch.Tensor) -> torch.Tensor:
        """Steps (:meth:`steps`) with Zm's in the nominal device's units of noise: times
        ``(|t12_nominal| / |t12|)²`` (with :meth:`reach_per_volt`, ``(batch, 1)``). Near the
        free tip ``dZm/dI_H = -t12² / E_H``, so the current channel's noise steps each
        device's Zm in proportion to ``|t12|²``, and |t12| at the probe (20 Hz above the first
        mode) spreads 0.5-1.4x over the trained devices: free whisking's median Zm step
        spread 8x between records (log-correlated 0.90 with ``|t12|²``), so one threshold
        called noise a touch on the devices of large |t12| and missed grazes on the others.
        A contact's own step (the wall's Zm) does not scale with the device."""
        if self.per_volt_ref <= 0:
            return step
        k = (per_volt / self.per_volt_ref) ** 2  # (|t12_nominal| / |t12|)², (batch, 1)
        return torch.cat([step[..., :1], step[..., 1:] * k[..., None]], -1)

    def reach_per_volt(self, t_re: torch.Tensor, t_im: torch.Tensor) -> torch.Tensor:
        """The calibrated free tip's probe amplitude per probe volt, ``1/(ωH |t12|)`` (m/V),
        ``(batch, 1)``, from each record's T at the probe ``(batch, 4)``."""
        t12 = torch.sqrt(t_re[:, 1:2] * t_re[:, 1:2] + t_im[:, 1:2] * t_im[:, 1:2])
        return 1.0 / (self.probe_omega * t12)

    @staticmethod
    def reach(f: torch.Tensor, per_volt: torch.Tensor) -> torch.Tensor:
        """The free tip's reach on the probe peaks, ``u_L + |u_H|`` (m), ``(batch, n)``, with
        :meth:`reach_per_volt`."""
        return f[..., 0] + per_volt * f[..., 3]

    def per_frame(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                  t_im: torch.Tensor, hue0: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per frame, each ``(batch, n_frames)``: ``contact`` logit, ``vote``/``est``/
        ``log_sd`` of g (m), ``vote_off``/``est_off`` of the detachment level (m),
        ``reach`` (m), ``touch`` (Zm's step over :attr:`touch_step`: >= 1 on a touch) and
        ``level`` (each frame's mean current, A: :func:`~wtml.decoders.wall_motion.frame_means`)."""
        f = self.frames(e, i, t_re, t_im, hue0)
        per_volt = self.reach_per_volt(t_re, t_im)
        return self.split(f, self.scaled(self.steps(f, f[:, :1, :3]), per_volt),
                          per_volt) | {"level": frame_means(i, self.frames.period)}

    def split(self, f: torch.Tensor, step: torch.Tensor, per_volt: torch.Tensor
              ) -> dict[str, torch.Tensor]:
        """The heads of frames ``f`` ``(batch, n, 5)`` with their steps (:meth:`scaled`) and
        the records' reach per volt (:meth:`reach_per_volt`)."""
        return self.outputs(self.head(self.body(self.inputs(f, step))), f, step, per_volt)

    def inputs(self, f: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """The convolution's input ``(batch, 8, n)``: normalised frames (held within
        :data:`FRAME_CLIP` std), u_L's step, and Zm's step as ``asinh(step / zm_step)`` (a
        first touch's step is ~1e3 zm_step)."""
        x = ((f - self.mean) / self.std).clamp(-FRAME_CLIP, FRAME_CLIP)
        du = step[..., :1] / self.std[0] * 10.0
        return torch.cat([x, du, asinh(step[..., 1:] / self.zm_step)], -1).transpose(1, 2)

    def outputs(self, h: torch.Tensor, f: torch.Tensor, step: torch.Tensor,
                per_volt: torch.Tensor) -> dict[str, torch.Tensor]:
        """The per-frame quantities (see :meth:`per_frame`) from the heads ``(batch, 6, n)``,
        the frames, their steps and the records' reach per volt."""
        # g and the detachment level relative to the free tip's reach on the probe peaks, not
        # u_L: the tip touches where u_L + |u_H| passes g, and |u_H| (0.22 µm at the nominal
        # device) is each device's own, |t12| at the probe spreading 0.5-1.4x over the trained
        # devices, which the net does not see (its frames hold |E_H|, the same for all)
        reach = self.reach(f, per_volt)
        zm = step[..., 1:]
        return {"contact": h[:, 0], "vote": h[:, 1], "est": reach + self.amp * h[:, 2],
                "log_sd": h[:, 3], "vote_off": h[:, 4], "est_off": reach + self.amp * h[:, 5],
                "reach": reach,
                "touch": torch.sqrt((zm * zm).sum(-1)) / self.touch_step}

    def pooled(self, p: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """``(g, sd, detachment level)``, m, each ``(batch,)``, and the frames' votes for g
        ``(batch, n)`` (softmax, summing to 1; :meth:`per_look` splits them by look)."""
        w = torch.softmax(p["vote"], -1)
        g = (w * p["est"]).sum(-1)
        var = (w * torch.exp(2 * p["log_sd"])).sum(-1) * self.amp**2
        off = (torch.softmax(p["vote_off"], -1) * p["est_off"]).sum(-1)
        return g, torch.sqrt(var), off, w

    @property
    def looks(self) -> int:
        """How many looks at the wall a record holds: each whisk cycle's approach and retreat
        (the tip's far end is at a cycle's start and end, its reach at the wall's side at its
        middle: the drive is ``-cos``)."""
        return 2 * self.cycles

    def look_of(self, frame: torch.Tensor) -> torch.Tensor:
        """One-hot look of each frame index (any shape ``s``, counted from the record's
        start) -> ``(*s, looks)`` float: ``2c`` the approach of whisk cycle c (its first half),
        ``2c + 1`` its retreat, by where the frame's middle falls in the whisk (frame f spans
        probe periods f to f + 1, a cycle :attr:`cycle_frames` of them, whole or not, so the
        looks keep to the whisk's phase over any number of cycles; a middle exactly at the
        half-cycle is the retreat's, and with a whole, even count the looks are the integer
        rule's, ``f mod cycle_frames < cycle_frames / 2`` the approach); a frame past the
        record's cycles is its last cycle's retreat."""
        at = (frame + 0.5) / self.cycle_frames  # whisk cycles from the record's start
        k = torch.floor(at).clamp(max=self.cycles - 1)
        look = 2 * k + (at - k >= 0.5).to(k.dtype)
        return (look[..., None] == torch.arange(self.looks, dtype=k.dtype)).float()

    def per_look(self, w: torch.Tensor, est: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """g's vote share and Σ w·estimate (m) of each look (:meth:`look_of`), ``(batch,
        looks)`` each (their sums over the looks are 1 and :meth:`pooled`'s g), from the
        frames' votes ``w`` (:meth:`pooled`'s) and estimates ``est`` (m), ``(batch, n)``
        each."""
        onehot = self.look_of(torch.arange(w.shape[1]))
        return w @ onehot, (w * est) @ onehot

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor, hue0: torch.Tensor) -> tuple[torch.Tensor, ...]:
        p = self.per_frame(e, i, t_re, t_im, hue0)
        g, sd, off, w = self.pooled(p)
        n = e.shape[0]
        prob, _, _ = confirm(torch.sigmoid(p["contact"]), p["touch"],
                             torch.zeros(n, CONFIRM_FRAMES), torch.zeros(n))
        gap, sd, off_margin = answer(g, sd, prob.amax(-1), p, off)
        spread = self.agreement(*self.per_look(w, p["est"]), gap, sd)
        motion = (torch.zeros_like(hue0) if self.motion is None
                  else self.motion(p["level"], prob, hue0))
        sd, share = self.widened(gap, sd, motion)
        return gap, sd, prob, off_margin, p["touch"], share, spread

    def widened(self, gap: torch.Tensor, sd: torch.Tensor, motion: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """σ with the wall's own motion in it, and that motion's share of the net's σ, from
        the wall's rms motion ``motion`` (m; :class:`~wtml.decoders.wall_motion.WallMotion`),
        ``(batch,)`` each: each of the :attr:`looks` meets the wall where it then was, so
        the answer, their pooled whole, is off by ``motion / √looks``; σ is the net's and
        that in quadrature, the share ``motion / (√looks σ_net)`` (0 without a wall; the
        exported graphs flag an answer whose share passes :data:`MOTION_LIMIT`)."""
        part = motion / float(np.sqrt(self.looks))
        share = torch.where(torch.isfinite(gap), part / sd, torch.zeros_like(part))
        return torch.sqrt(sd * sd + part * part), share

    def agreement(self, share: torch.Tensor, sums: torch.Tensor, gap: torch.Tensor,
                  sd: torch.Tensor) -> torch.Tensor:
        """:func:`touch_spread` of the looks' ``share`` and ``sums`` ``(batch, looks)``;
        0 for records of one whisk cycle (nothing to compare: only rounding would show)."""
        if self.cycles == 1:
            return torch.zeros_like(gap)
        return touch_spread(share, sums, gap, sd)


CONFIRM_FRAMES = 4
"""Frames before a frame in which a touch (Zm's step over the threshold) confirms its contact
probability (:func:`confirm`; the runtime looks as far back for the onset,
:data:`TOUCH_LOOKBACK`)."""


TOUCH_LOOKBACK = 4
"""Frames ahead of a decoder's contact run in which its first touch is still looked for (the
run starts where the reach passes the detachment level or the probability passes 0.5,
either of which can come a frame or two after the first touch)."""

def confirm(prob: torch.Tensor, touch: torch.Tensor, past: torch.Tensor, seen: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The contact probabilities a record reports: none until its first contact is confirmed,
    a frame whose probability passes 0.5 with a touch (``touch >= 1``) in it or in the
    :data:`CONFIRM_FRAMES` frames before; from then on the net's. (On a noisy acquisition
    the net's probability near the whisk's far end rises towards 0.5 on free whisking, where
    Zm steps no more than the noise; a wall's first contact always steps it.) Causal:
    ``past`` ``(batch, CONFIRM_FRAMES)`` the touches before the first frame and ``seen``
    ``(batch,)`` the confirmations before it (zeros at a record's start) -> the reported
    probabilities ``(batch, n)``, the last touches and the confirmations after."""
    x = torch.cat([past, touch], 1)
    near = fn.max_pool1d(x[:, None], CONFIRM_FRAMES + 1, stride=1)[:, 0]  # (batch, n)
    hit = ((prob > 0.5) & (near >= 1)).to(prob.dtype)
    count = seen[:, None] + torch.cumsum(hit, 1)
    return (prob * (count > 0).to(prob.dtype), x[:, x.shape[1] - CONFIRM_FRAMES:],
            count[:, -1])


def touch_spread(share: torch.Tensor, sums: torch.Tensor, gap: torch.Tensor, sd: torch.Tensor
                 ) -> torch.Tensor:
    """How far each whisk cycle's approach and retreat locate the wall from the record's
    approach and retreat, in its σ, ``(batch,)``:
    ``sqrt(Σ_c Σ_h W_ch (G_ch − Ḡ_h)²) / σ``, from each look's (:meth:`OnsetNet.look_of`:
    cycle c, h its approach or retreat) vote share ``W_ch`` and ``Σ w·estimate`` (``G_ch``
    their ratio), ``share`` and ``sums`` ``(batch, looks)``; ``Ḡ_h`` is the record's
    share-weighted mean of the h looks, so a bias that the net gives every approach (or every
    retreat) alike cancels (the main job's decoder's approach frames read the wall 18–46σ
    beyond its retreat frames, and only their vote-weighted whole is g). ``gap`` (m) only
    marks a record without contact (NaN: 0 there); σ in m. For two cycles of equal shares it
    is ``sqrt((Δ_a² + Δ_r²) / 8) / σ`` with ``Δ_h = G_1h − G_2h``: the cycles' disagreement
    ``|G_1 − G_2| / 2σ`` (``G_c`` the cycle's whole) and their approach-minus-retreat
    differences' disagreement over 4σ, in quadrature. A still wall is met at one place in
    every look. An object moving with the floor (0.8 µm rms at 5–20 Hz, physics.md §12) is
    met at four places, the tip touching and leaving it 0.1–0.4 s apart: of the main job's
    decoder's answers on 453 such walls, a limit that 0.1 % of 438 trained walls pass flags
    96.0 % (the cycles' whole alone: 76.6 %), and no other row of the transfer table loses
    more than 0.4 % of its answers to it. A graph compares it with a limit fitted on fresh
    records of the trained scene (:class:`~wtml.decoders.domain.Gated`'s ``check``)."""
    if share.shape[1] % 2 or sums.shape != share.shape:
        raise ValueError(f"touch_spread: shares and sums of an approach and a retreat per whisk "
                         f"cycle, (batch, 2·cycles) each, got {tuple(share.shape)} and "
                         f"{tuple(sums.shape)}")
    share, sums = share.unflatten(1, (-1, 2)), sums.unflatten(1, (-1, 2))
    mean = sums / share.clamp_min(1e-30)
    side = sums.sum(1) / share.sum(1).clamp_min(1e-30)
    spread = torch.sqrt((share * (mean - side[:, None]) ** 2).sum((1, 2))) / sd
    return torch.where(torch.isfinite(gap), spread, torch.zeros_like(spread))


def answer(g, sd, top, p: dict, off) -> tuple[torch.Tensor, ...]:
    """The location and detachment margin from the pooled quantities (``(batch,)``, m), the
    record's highest contact probability ``top`` ``(batch,)`` and the per-frame reach
    ``p["reach"]`` (m, ``(batch, n)``): ``(gap, sigma, detach_margin)``.

    One decision gives the wall and the contacts: a record touches a wall where a frame's
    contact probability passes 0.5, and a contact starts on each such run of frames
    (:func:`wtml.runtime.contacts.contacts_from`); only then are g and σ reported. Otherwise gap
    and σ are NaN ("no wall": free whisking) and the margins -1 m (no interval)."""
    touched = top > 0.5
    nan, never = torch.full_like(g, float("nan")), torch.full_like(p["reach"], -1.0)
    return (torch.where(touched, g, nan), torch.where(touched, sd, nan),
            torch.where(touched[:, None], p["reach"] - off[:, None], never))


def frame_labels(targets: torch.Tensor, n_frames: int, frame_s: float, max_contacts: int
                 ) -> torch.Tensor:
    """Whether each frame overlaps a true contact, ``(batch, n_frames)`` float, from targets
    ``[gap, onsets (max_contacts), detachments (max_contacts), coupling]``."""
    start = torch.arange(n_frames, dtype=targets.dtype) * frame_s
    on = targets[:, 1:1 + max_contacts, None]
    off = targets[:, 1 + max_contacts:1 + 2 * max_contacts, None]
    off = torch.where(torch.isnan(off) & ~torch.isnan(on), torch.full_like(off, 1e9), off)
    hit = (start < off) & (start + frame_s > on)
    return hit.any(1).float()


def onset_frames(targets: torch.Tensor, n_frames: int, frame_s: float, max_contacts: int
                 ) -> torch.Tensor:
    """The frame that holds each true onset and the frame before it (the decision's edge),
    ``(batch, n_frames)`` float 0/1, from targets as :func:`frame_labels`."""
    on = targets[:, 1:1 + max_contacts]
    k = torch.floor(torch.nan_to_num(on, -1.0) / frame_s).long()
    out = torch.zeros(len(targets), n_frames + 1, dtype=targets.dtype)
    for shift in (0, -1):
        at = torch.where(torch.isfinite(on), (k + shift).clamp(0, n_frames - 1), n_frames)
        out.scatter_(1, at, 1.0)
    return out[:, :n_frames]


def touch_threshold(step: np.ndarray, targets: np.ndarray, frame_s: float, max_contacts: int,
                    lookback: int | None = None, grid: int = 400) -> float:
    """The size of Zm's frame-to-frame step (N·s/m) that marks a first touch, chosen on the
    training data for the rule that uses it (:func:`wtml.runtime.contacts.contacts_from`: the
    first frame over it, from ``lookback`` frames ahead of a contact up to the contact).
    Each training onset is called on its own frame iff its step reaches the threshold and
    none of the ``lookback`` frames of free whisking before it does; the threshold is the
    geometric middle of the widest stretch of a log grid (``grid`` points over the steps'
    range) where the most onsets are called right. So it follows the acquisition: on a quiet
    one, free whisking's steps are ~1e-7 N·s/m and a first touch's 1e-6 and more; with the
    converter's noise and the ADC floor the free steps reach a few 1e-6, and the threshold
    moves up to where a few grazes are given up rather than calling noise.
    ``step`` ``(n, n_frames)`` the steps' size, targets as :func:`frame_labels`; 1.0
    without an onset."""
    if lookback is None:
        lookback = TOUCH_LOOKBACK
    on = targets[:, 1:1 + max_contacts]
    first, ahead = [], []
    for r, k in zip(*np.nonzero(np.isfinite(on)), strict=True):
        j = int(on[r, k] // frame_s)
        if lookback <= j < step.shape[1]:
            first.append(step[r, j])
            ahead.append(step[r, j - lookback:j].max())
    first, ahead = np.asarray(first), np.asarray(ahead)
    values = np.concatenate([first, ahead])
    values = values[values > 0]
    if not len(values):
        return 1.0
    levels = np.geomspace(values.min(), values.max(), grid)
    right = ((first[:, None] >= levels) & (ahead[:, None] < levels)).sum(0)
    best = right == right.max()
    # the widest run of the best levels: its geometric middle
    edges = np.flatnonzero(np.diff(np.concatenate([[0], best.astype(int), [0]])))
    runs = edges.reshape(-1, 2)
    lo, hi = runs[np.argmax(runs[:, 1] - runs[:, 0])]
    return float(np.sqrt(levels[lo] * levels[hi - 1]))


def detach_brackets(targets: torch.Tensor, reach: torch.Tensor, frame_s: float,
                    max_contacts: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Where the detachment level must lie for the timing rule to end each true contact in
    its frame: ``(low, high)``, each ``(batch, max_contacts)`` m, NaN where a record has fewer
    contacts. A contact ending in frame j needs ``reach[j+1] < level <= reach[j]``."""
    n = reach.shape[1]
    off = targets[:, 1 + max_contacts:1 + 2 * max_contacts]

    def at(shift: int) -> torch.Tensor:
        k = torch.floor(torch.nan_to_num(off) / frame_s).long() + shift
        v = reach.gather(1, k.clamp(0, n - 1))
        return torch.where(torch.isfinite(off), v, torch.full_like(v, float("nan")))

    return at(1), at(0)


def edge_offsets(targets: np.ndarray, frame_s: float, max_contacts: int) -> tuple[float, float]:
    """Median phase (s) within its frame at which training contacts start and end."""
    on = targets[:, 1:1 + max_contacts].ravel()
    off = targets[:, 1 + max_contacts:1 + 2 * max_contacts].ravel()
    on, off = on[np.isfinite(on)], off[np.isfinite(off)]
    if not len(on):
        return 0.0, frame_s
    return (float(np.median(on - np.floor(on / frame_s) * frame_s)),
            float(np.median(off - np.floor(off / frame_s) * frame_s)) if len(off) else frame_s)


class OnsetDecoder(DecoderModule):
    """The onset decoder (``configs/onset.yaml``).

    Args:
        channels: width of the temporal convolution.
        dilations: its layers' dilations (receptive field ``1 + 2 Σ d`` frames at kernel 3).
        contact_weight: weight of the frames' contact BCE (it sets how soon the streaming
            form sees a contact: the location's NLL, whose gradient grows as its std
            shrinks, otherwise starves it).
        onset_weight: extra weight of the BCE on each contact's first frame and the frame
            before it (:func:`onset_frames`): where the onset is decided.
        location_weight: weight of the location's Gaussian NLL.
        timing_weight: weight of the detachment level's log-cosh loss (:data:`LEVEL_SCALE`),
            towards the middle of its brackets (:func:`detach_brackets`).
        mains_lines: remove the mains lines (the scene's ``acquisition.effects.hum``
            frequency and its harmonics' count, whether or not the scene simulates hum) from
            each probe frame's fit, estimated causally in the graph (:class:`MainsLines`),
            and take Zm through the probe voltage's running mean over the record (the
            drive's, which a contact does not change) rather than each frame's.
        lr, weight_decay: as every decoder.
    """

    TASK = "onset"

    def __init__(self, channels: int = 32, dilations: list[int] | None = None,
                 contact_weight: float = 30.0, onset_weight: float = 10.0,
                 location_weight: float = 1.0, timing_weight: float = 1.0,
                 mains_lines: bool = True, lr: float = 3e-3, weight_decay: float = 1e-5) -> None:
        super().__init__(lr, weight_decay)
        dilations = [1, 2, 4, 8, 16] if dilations is None else list(dilations)
        if not 1 <= channels <= 1024:
            raise ConfigError(f"model.channels must be in [1, 1024], got {channels!r}")
        if not dilations or any(not 1 <= d <= 4096 for d in dilations):
            raise ConfigError(f"model.dilations must be a non-empty list of values in "
                              f"[1, 4096], got {dilations!r}")
        check_positive("model.contact_weight", contact_weight, 1e6)
        if not 0 <= onset_weight <= 1e6:
            raise ConfigError(f"model.onset_weight must be in [0, 1e6], got {onset_weight!r}")
        check_positive("model.location_weight", location_weight, 1e6)
        check_positive("model.timing_weight", timing_weight, 1e6)
        self.save_hyperparameters()
        self.register_buffer("offsets", torch.zeros(2))

    def _frames(self, scene) -> ProbeFrames:
        period = frame_period(scene)
        mains = None
        if self.hparams.get("mains_lines", False):
            hum = scene.acquisition.effects.hum  # the lab's mains, whether or not simulated
            lines = [MainsLines(period, scene.drive.probe_hz, hum.mains_hz,
                                1 + len(hum.harmonics), scene.n_samples // period,
                                gated=gated) for gated in (False, True)]
            mains = (lines[0], lines[1])
        # the tip cannot touch while u_L is below the nearest wall less twice the probe's
        # reach on it (the nominal free tip's |u_H| = |E_H| / (ωH |t12|); a device of the
        # spread differs by a few %)
        wh = 2 * np.pi * scene.drive.probe_hz
        reach = scene.drive.probe_v / (wh * nominal_t12(scene))
        return ProbeFrames(period, mains, free_below=scene.gap_range_m()[0] - 2 * reach)

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        return RecordSummary(self._frames(scene)), 3 + RecordSummary.N_DEVICE

    def _make(self, scene, scale: torch.Tensor, zm_step: torch.Tensor | None = None,
              touch_step: float = 1.0) -> OnsetNet:
        h = self.hparams
        return OnsetNet(self._frames(scene), scale,
                        torch.ones(2) if zm_step is None else zm_step, touch_step,
                        scene.whisk_amplitude_m(), 2 * np.pi * scene.drive.probe_hz,
                        h.channels, tuple(h.dilations),
                        cycle_frames=max(1.0, scene.drive.probe_hz / scene.drive.whisk_hz),
                        cycles=int(np.ceil(scene.drive.cycles - 1e-9)), t12=nominal_t12(scene),
                        wall_stiffness=series_stiffness(scene),
                        mains_hz=scene.acquisition.effects.hum.mains_hz)

    def build_net(self, scene, *tensors) -> nn.Module:
        *inputs, targets = tensors
        frames = self._frames(scene)
        with torch.no_grad():
            f = torch.cat([frames(*(x[s:s + 64] for x in inputs))
                           for s in range(0, len(targets), 64)])
        # the statistics leave out the frames of the largest |Zm| (1 in 10^4): a frame whose
        # tip velocity phasor nearly vanishes (a contact switching inside it) reads |Zm| ~100x
        # a wall's, and one such frame in the training data (met over the device spread: 0.31
        # N·s/m against ~2e-3) set the floor below, hence the touch threshold, 6x too high
        flat = f.flatten(0, 1)
        zm = flat[:, 1:3].norm(dim=-1)
        flat = flat[zm <= torch.quantile(zm.double(), 0.9999).float()]
        # a feature the data hold nearly constant (the probe level) is scaled no finer than
        # float32 resolves it, or rounding differences between graphs would drive the net
        floor = RESOLUTION * flat.abs().amax(0)
        scale = torch.stack([flat.mean(0), torch.maximum(flat.std(0), floor)])
        # Zm's steps in the nominal device's noise units (OnsetNet.scaled)
        ref = self._make(scene, scale)
        step = ref.scaled(OnsetNet.steps(f, f[:, :1, :3]),
                          ref.reach_per_volt(inputs[2], inputs[3]))[..., 1:]
        zm_step = torch.maximum(step.abs().flatten(0, 1).median(0).values, floor[1:3])
        frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
        self.offsets.copy_(torch.tensor(edge_offsets(targets.numpy(), frame_s,
                                                     scene.max_contacts)))
        self._frame_s, self._max_contacts = frame_s, scene.max_contacts
        # the rule (contacts_from) starts a contact where its last run of touches starts: an
        # onset is called right iff its own frame's step passes and the frame before's does not
        touch = touch_threshold(step.norm(dim=-1).double().numpy(), targets.numpy(), frame_s,
                                scene.max_contacts, lookback=1)
        return self._make(scene, scale, zm_step, max(touch, float(floor[1:3].max())))

    def net_shape(self) -> dict:
        return {}

    def build_from_checkpoint(self, shape: dict) -> None:
        from wtml.scenes import scene_from_dict

        scene = scene_from_dict(self.scene)
        self.net = self._make(scene, torch.ones(2, 5))
        self._frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
        self._max_contacts = scene.max_contacts

    def loss(self, batch) -> torch.Tensor:
        *inputs, targets = batch
        p = self.net.per_frame(*inputs)
        n = p["contact"].shape[1]
        labels = frame_labels(targets, n, self._frame_s, self._max_contacts)
        weight = 1 + self.hparams.onset_weight * onset_frames(targets, n, self._frame_s,
                                                              self._max_contacts)
        bce = self.hparams.contact_weight * fn.binary_cross_entropy_with_logits(
            p["contact"], labels, weight=weight)
        g, sd, off, _ = self.net.pooled(p)
        has = torch.isfinite(targets[:, 0])
        if not has.any():
            return bce
        amp = self.net.amp
        z = (g[has] - targets[has, 0]) / amp
        s = sd[has] / amp
        nll = (0.5 * (z / s) ** 2 + torch.log(s)).mean()
        # the detachment level: the middle of its brackets (the two whisks' overlap)
        lo, hi = detach_brackets(targets, p["reach"], self._frame_s, self._max_contacts)
        timing = (off - torch.nanmean((lo + hi) / 2, 1)) / (LEVEL_SCALE * amp)
        timing = timing[torch.isfinite(timing)].abs()
        timing = (timing + torch.log1p(torch.exp(-2 * timing)) - np.log(2.0))  # log cosh
        timing = timing.sum() / max(timing.numel(), 1)
        return bce + self.hparams.location_weight * nll + self.hparams.timing_weight * timing


def nominal_t12(scene) -> float:
    """|t12| (V·s/m) of the scene's nominal device at the probe frequency."""
    wh = 2 * np.pi * scene.drive.probe_hz
    return float(abs(scene.transducer().transduction_matrix(np.array([wh]))[0, 0, 1]))


def frame_period(scene) -> int:
    """Samples per probe period; the scene's rate must be a whole multiple of the probe."""
    ratio = scene.acquisition.sample_rate_hz / scene.drive.probe_hz
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ConfigError(f"acquisition.sample_rate_hz {scene.acquisition.sample_rate_hz:g} "
                          f"must be a whole multiple of drive.probe_hz {scene.drive.probe_hz:g} "
                          "for the onset decoder's probe frames")
    return int(round(ratio))
