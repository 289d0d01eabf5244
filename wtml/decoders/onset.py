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
   of the preset, so the decoder maps each device through its own T.
2. A causal temporal convolution over the frames (dilated, so it sees ~60 frames back: the
   400 Hz mode rings for ~40 ms), fed the normalised frames, u_L's step and Zm's step from
   the frame before (compressed by asinh on the scale of free whisking's frame-to-frame
   jitter). Per frame: the contact logit, and for two quantities a vote weight and the
   frame's estimate (relative to the whisking position): the wall's location g (with a log
   std) and the *detachment level* (below). Because it is causal, the streaming form
   (:class:`StreamingOnset`, fed chunks, its state carried) gives the offline answer.
3. Each quantity is pooled over the frames by softmax weights, ``g = Σ_t w_t (u_L(t) + δ_t)``:
   each frame near an edge says where the wall is relative to the whisking position, which
   accounts for the tip touching on the probe's peaks before u_L reaches g (§10). g's
   variance is the same weighted mean of the frames' variances.
4. Timing. The first touch, on a probe peak, shows in its own frame as a step of Zm from
   the frame before (5e-6 N·s/m and more, where free whisking's frames differ by ~1e-7):
   the output ``touch`` is that step's size over a threshold, twice free whisking's largest
   step on the training data (:func:`touch_threshold`). A contact is a run of frames whose contact
   probability passes 0.5 (labels: the frames that hold a touching instant) and it starts
   on the first frame, from a few before the run up to its first such frame, whose
   ``touch`` is >= 1 (:func:`wtml.runtime.onset.contacts_from`). (Taking the onset from the
   trajectory instead, the first frame whose reach passes a learned level, needs that level
   to ~10 nm: the frames' reach brackets are 0.09-0.19 µm wide and the true level is often
   within 10 nm of an edge; the main job's small training got it to 34 nm, and every miss
   was one probe period early or late.) A first touch that only grazes its probe peak
   (a few nm) steps Zm no more than free whisking does, and the onset is then called one
   frame late. A contact ends on the last frame whose reach on the probe peaks, ``u_L + |u_H|``
   (``|u_H| = |E_H| / (ωH |t12|)``, the calibrated free-tip response, known per frame to
   ~1e-12 m from e alone), passes the detachment level, which the net estimates; the
   output ``detach_margin`` is reach minus that level per frame (m).

Inputs: ``e`` (V), ``i`` (A) ``(batch, n_samples)`` and the calibration ``t_re, t_im,
hue0``. The whisking amplitude of the nominal device (``amp``) is the unit of the net's
offsets only (a device's own amplitude differs by a few %, its offsets by as little).

Outputs (each ``(batch,)`` unless said): ``gap`` and ``sigma`` (m, NaN in a record without
contact: :func:`answer` decides wall and contacts together), ``contact`` (``(batch,
n_frames)``, probability per frame), ``detach_margin`` (m, ``(batch, n_frames)``; -1 m in a
record without contact) and ``touch`` (``(batch, n_frames)``).
Intervals come from these by :func:`wtml.runtime.onset.contacts_from` plus the
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

CALIBRATION = ("t_re", "t_im", "hue0")
"""The graph's inputs after ``e, i``: the user's calibrated T at the probe frequency, real and
imaginary parts ``(batch, 4)`` as ``T.reshape(4)`` (t11, t12, t21, t22), and HUE(0) (m/V,
``(batch,)``)."""

FRAME_CLIP = 30.0
"""Normalised frame features are held within ±this many training std before the convolution.
A contact's Zm is ~10 std; a frame in which a contact switches can read a nearly vanishing
tip velocity and |Zm| ~1000 std (met over the device spread: 0.31 N·s/m), which drove the
main job's training to NaN."""

LEVEL_SCALE = 0.001
"""The detachment level's loss is log cosh of its error in units of this fraction of the
whisking amplitude (13 nm at the defaults: quadratic below, linear above), so the loss stays
steep down to the scale of its brackets' edges."""


def frame_basis(period: int) -> np.ndarray:
    """Rows that take ``(e_L, cos-coefficient, sin-coefficient)`` out of one probe period of
    ``period`` samples by least squares on ``[1, t, t², cos, sin]`` (t centred), shape
    ``(3, period)``."""
    t = np.arange(period) - (period - 1) / 2
    w = 2 * np.pi / period
    n = np.arange(period)
    basis = np.stack([np.ones(period), t / period, (t / period) ** 2,
                      np.cos(w * n), np.sin(w * n)], 1)
    pinv = np.linalg.pinv(basis)
    return pinv[[0, 3, 4]]


class ProbeFrames(nn.Module):
    """``(e, i)`` ``(batch, n_samples)`` and the calibration (:data:`CALIBRATION`) -> frames
    ``(batch, n_frames, 5)``: ``u_L`` (m), ``Re Zm, Im Zm`` (N·s/m), ``|E_H|`` (V), and
    ``|I_H| / (|Y_free| |E_H|)``, the probe current over what the device's free tip draws
    (``Y_free = t22/t12``, from Zm = 0): 1 on free whisking for every device, where
    ``|I_H|`` itself differs between devices by more than a contact changes it.

    Args:
        period: samples per probe period (an integer: the scene's rate is a multiple of the
            probe frequency).
    """

    def __init__(self, period: int) -> None:
        super().__init__()
        self.period = int(period)
        self.register_buffer("basis", torch.tensor(frame_basis(self.period).T,
                                                   dtype=torch.float32))
        self.zm = ZmFromEI()

    def fit(self, x: torch.Tensor) -> torch.Tensor:
        """``(batch, n_samples)`` -> ``(batch, 3, n_frames)``: frame level, cos, sin.

        Each frame is fitted relative to its first sample (exact in float32), so rounding
        scales with the signal's change within a frame, not with its level: the whisking
        drive is ~500 times the probe, and a fit on the raw samples loses the probe's
        phasor to float32 rounding (graphs that sum in another order disagree there)."""
        n = x.shape[1] // self.period
        frames = x[:, :n * self.period].unflatten(1, (n, self.period))
        first = frames[..., :1]
        fit = ((frames - first) @ self.basis).transpose(1, 2)
        return fit + torch.cat([first[..., 0][:, None], torch.zeros_like(fit[:, 1:])], 1)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor, hue0: torch.Tensor) -> torch.Tensor:
        s = ZmFromEI.I_SCALE
        fe, fi = self.fit(e), self.fit(i * s)
        # x = c cos + s sin = Re(X e^{jωt}) with X = c - j s
        e_re, e_im, i_re, i_im = fe[:, 1], -fe[:, 2], fi[:, 1], -fi[:, 2]
        zm_re, zm_im = self.zm(e_re, e_im, i_re, i_im, t_re, t_im)
        mag_e = torch.sqrt(e_re * e_re + e_im * e_im)
        y_free = torch.sqrt((t_re[:, 3:] * t_re[:, 3:] + t_im[:, 3:] * t_im[:, 3:])
                            / (t_re[:, 1:2] * t_re[:, 1:2] + t_im[:, 1:2] * t_im[:, 1:2]))
        free = (s * y_free * mag_e).clamp_min(1e-30)  # µA
        return torch.stack([hue0[:, None] * fe[:, 0], zm_re, zm_im, mag_e,
                            torch.sqrt(i_re * i_re + i_im * i_im) / free], -1)


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
    m); see the module docstring.

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
    """

    HEADS = 6
    """Per frame: contact logit; vote, estimate, log std of g; vote, estimate of the
    detachment level."""

    def __init__(self, frames: ProbeFrames, scale: torch.Tensor, zm_step: torch.Tensor,
                 touch_step: float, amp: float, probe_omega: float, channels: int,
                 dilations: tuple[int, ...], kernel: int = 3) -> None:
        super().__init__()
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

    @staticmethod
    def steps(f: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """The step of (u_L m, Re Zm, Im Zm N·s/m) from the frame before, ``(batch, n, 3)``,
        given those of the frame before the first, ``(batch, 1, 3)``."""
        x = torch.cat([previous, f[..., :3]], 1)
        return x[:, 1:] - x[:, :-1]

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
        ``reach`` (m) and ``touch`` (Zm's step over :attr:`touch_step`: >= 1 on a touch)."""
        f = self.frames(e, i, t_re, t_im, hue0)
        return self.split(f, self.steps(f, f[:, :1, :3]), self.reach_per_volt(t_re, t_im))

    def split(self, f: torch.Tensor, step: torch.Tensor, per_volt: torch.Tensor
              ) -> dict[str, torch.Tensor]:
        """The heads of frames ``f`` ``(batch, n, 5)`` with their steps (:meth:`steps`) and
        the records' reach per volt (:meth:`reach_per_volt`)."""
        return self.outputs(self.head(self.body(self.inputs(f, step))), f, step, per_volt)

    def inputs(self, f: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """The convolution's input ``(batch, 8, n)``: normalised frames (held within
        :data:`FRAME_CLIP` std), u_L's step, and Zm's step as ``asinh(step / zm_step)`` (a
        first touch's step is ~1e3 zm_step)."""
        x = ((f - self.mean) / self.std).clamp(-FRAME_CLIP, FRAME_CLIP)
        du = step[..., :1] / self.std[0] * 10.0
        return torch.cat([x, du, torch.asinh(step[..., 1:] / self.zm_step)], -1).transpose(1, 2)

    def outputs(self, h: torch.Tensor, f: torch.Tensor, step: torch.Tensor,
                per_volt: torch.Tensor) -> dict[str, torch.Tensor]:
        """The per-frame quantities (see :meth:`per_frame`) from the heads ``(batch, 6, n)``,
        the frames, their steps and the records' reach per volt."""
        u = f[..., 0]
        zm = step[..., 1:]
        return {"contact": h[:, 0], "vote": h[:, 1], "est": u + self.amp * h[:, 2],
                "log_sd": h[:, 3], "vote_off": h[:, 4], "est_off": u + self.amp * h[:, 5],
                "reach": self.reach(f, per_volt),
                "touch": torch.sqrt((zm * zm).sum(-1)) / self.touch_step}

    def pooled(self, p: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """``(g, sd, detachment level)``, m, each ``(batch,)``."""
        w = torch.softmax(p["vote"], -1)
        g = (w * p["est"]).sum(-1)
        var = (w * torch.exp(2 * p["log_sd"])).sum(-1) * self.amp**2
        off = (torch.softmax(p["vote_off"], -1) * p["est_off"]).sum(-1)
        return g, torch.sqrt(var), off

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor, hue0: torch.Tensor) -> tuple[torch.Tensor, ...]:
        p = self.per_frame(e, i, t_re, t_im, hue0)
        g, sd, off = self.pooled(p)
        prob = torch.sigmoid(p["contact"])
        gap, sd, off_margin = answer(g, sd, prob.amax(-1), p, off)
        return gap, sd, prob, off_margin, p["touch"]


def answer(g, sd, top, p: dict, off) -> tuple[torch.Tensor, ...]:
    """The location and detachment margin from the pooled quantities (``(batch,)``, m), the
    record's highest contact probability ``top`` ``(batch,)`` and the per-frame reach
    ``p["reach"]`` (m, ``(batch, n)``): ``(gap, sigma, detach_margin)``.

    One decision gives the wall and the contacts: a record touches a wall where a frame's
    contact probability passes 0.5, and a contact starts on each such run of frames
    (:func:`wtml.runtime.onset.contacts_from`); only then are g and σ reported. Otherwise gap
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
                    before: int = 40, factor: float = 2.0) -> float:
    """The size of Zm's frame-to-frame step (N·s/m) that marks a first touch: ``factor``
    times the largest step over free whisking, the ``before`` frames ahead of each training
    onset. (A first touch steps Zm by 1e-6 N·s/m and more in 97 % of the scene's records,
    where free whisking's largest step is ~2.5e-7; placing the threshold from the free side
    keeps it clear of the grazes, some of which step Zm no more than free whisking.)
    ``step`` ``(n, n_frames)`` the steps' size, targets as :func:`frame_labels`; 1.0
    without an onset."""
    on = targets[:, 1:1 + max_contacts]
    free = [step[r, j - before:j].max()
            for r, k in zip(*np.nonzero(np.isfinite(on)), strict=True)
            for j in [int(on[r, k] // frame_s)] if before <= j < step.shape[1]]
    return factor * float(max(free)) if free else 1.0


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
        lr, weight_decay: as every decoder.
    """

    def __init__(self, channels: int = 32, dilations: list[int] | None = None,
                 contact_weight: float = 30.0, onset_weight: float = 10.0,
                 location_weight: float = 1.0, timing_weight: float = 1.0, lr: float = 3e-3,
                 weight_decay: float = 1e-5) -> None:
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

    @staticmethod
    def _frames(scene) -> ProbeFrames:
        return ProbeFrames(frame_period(scene))

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        return RecordSummary(self._frames(scene)), 3 + RecordSummary.N_DEVICE

    def _make(self, scene, scale: torch.Tensor, zm_step: torch.Tensor | None = None,
              touch_step: float = 1.0) -> OnsetNet:
        h = self.hparams
        return OnsetNet(self._frames(scene), scale,
                        torch.ones(2) if zm_step is None else zm_step, touch_step,
                        scene.whisk_amplitude_m(), 2 * np.pi * scene.drive.probe_hz,
                        h.channels, tuple(h.dilations))

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
        step = OnsetNet.steps(f, f[:, :1, :3])[..., 1:]
        zm_step = torch.maximum(step.abs().flatten(0, 1).median(0).values, floor[1:3])
        frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
        self.offsets.copy_(torch.tensor(edge_offsets(targets.numpy(), frame_s,
                                                     scene.max_contacts)))
        self._frame_s, self._max_contacts = frame_s, scene.max_contacts
        touch = touch_threshold(step.norm(dim=-1).double().numpy(), targets.numpy(), frame_s,
                                scene.max_contacts)
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
        g, sd, off = self.net.pooled(p)
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


def frame_period(scene) -> int:
    """Samples per probe period; the scene's rate must be a whole multiple of the probe."""
    ratio = scene.acquisition.sample_rate_hz / scene.drive.probe_hz
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ConfigError(f"acquisition.sample_rate_hz {scene.acquisition.sample_rate_hz:g} "
                          f"must be a whole multiple of drive.probe_hz {scene.drive.probe_hz:g} "
                          "for the onset decoder's probe frames")
    return int(round(ratio))
