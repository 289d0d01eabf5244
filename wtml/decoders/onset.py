"""The contact-onset decoder: wall location and contact intervals from e(t), i(t).

The graph takes the raw records and computes its own features per probe period (the frames:
64 samples at the defaults), so a device feeds it what its ADC gives:

1. :class:`ProbeFrames`: per frame, a least-squares fit of ``[1, t, t², cos ωH t, sin ωH t]``
   to e and to i, relative to the frame's first sample for float32 (the polynomial soaks up
   the whisking ramp, which would otherwise leak into the probe's phasor): the whisking
   position ``u_L = HUE(0) e_L`` and the probe phasors
   ``E_H, I_H``, then ``Zm = (t22 E_H - t12 I_H)/(t11 I_H - t21 E_H)`` through the
   calibrated T at the probe frequency (real arithmetic, exportable).
2. A causal temporal convolution over the frames (dilated, so it sees ~60 frames back: the
   400 Hz mode rings for ~40 ms). Per frame: the contact logit, and for each of three
   quantities a vote weight and the frame's estimate (relative to the whisking position):
   the wall's location g (with a log std), and the *reach levels* at which contacts start and
   end (below). Because it is causal, the streaming form (:class:`StreamingOnset`, fed chunks,
   its state carried) gives the offline answer.
3. Each quantity is pooled over the frames by softmax weights, ``g = Σ_t w_t (u_L(t) + δ_t)``:
   each frame near an edge says where the wall is relative to the whisking position, which
   accounts for the tip touching on the probe's peaks before u_L reaches g (§10). g's
   variance is the same weighted mean of the frames' variances.
4. Timing from the trajectory: the free tip reaches ``u_L + |u_H|`` on each probe peak
   (``|u_H| = |E_H| / (ωH |t12|)``, the calibrated free-tip response), known per frame to
   ~1e-12 m from e alone. A contact starts on the first frame whose reach on its probe peak
   (the frame's reach moved to the peak's phase, from u_L's step) passes the onset level, and
   ends on the last frame whose reach passes the detachment level. The levels are in the
   calibrated model's units: the onset level is the wall as the calibrated model sees it,
   ``g / s`` for a device whose coupling is ``s`` times the calibrated one (less a small
   bias fitted on the training data), so the timing does not depend on the calibration
   error. The outputs ``onset_margin``/``detach_margin`` are reach minus level per frame (m).

Outputs (each ``(batch,)`` unless said): ``gap`` and ``sigma`` (m, NaN in a record without
contact: :func:`answer` decides wall and contacts together), ``contact`` (``(batch,
n_frames)``, probability per frame), ``onset_margin`` and ``detach_margin`` (m, ``(batch,
n_frames)``; -1 m in a record without contact).
Intervals come from the margins by :func:`wtml.runtime.onset.contacts_from` plus the
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

LEVEL_SCALE = 0.001
"""The reach levels' loss is log cosh of their error in units of this fraction of the
whisking amplitude (13 nm at the defaults: quadratic below, linear above). The onset level
must land in a bracket of 0.11-0.19 µm, often within ~10 nm of its edge, so the loss stays
steep down to that scale."""


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
    """``(e, i)`` ``(batch, n_samples)`` -> frames ``(batch, n_frames, 5)``: ``u_L`` (m),
    ``Re Zm, Im Zm`` (N·s/m), ``|E_H|`` (V), ``|I_H|`` (A).

    Args:
        period: samples per probe period (an integer: the scene's rate is a multiple of the
            probe frequency).
        t_probe: complex T at the probe frequency ``(2, 2)``.
        hue0: HUE(0), m/V.
    """

    def __init__(self, period: int, t_probe: np.ndarray, hue0: float) -> None:
        super().__init__()
        self.period = int(period)
        self.register_buffer("basis", torch.tensor(frame_basis(self.period).T,
                                                   dtype=torch.float32))
        self.zm = ZmFromEI(t_probe)
        self.hue0 = float(hue0)

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

    def forward(self, e: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        s = ZmFromEI.I_SCALE
        fe, fi = self.fit(e), self.fit(i * s)
        # x = c cos + s sin = Re(X e^{jωt}) with X = c - j s
        e_re, e_im, i_re, i_im = fe[:, 1], -fe[:, 2], fi[:, 1], -fi[:, 2]
        zm_re, zm_im = self.zm(e_re, e_im, i_re, i_im)
        return torch.stack([self.hue0 * fe[:, 0], zm_re, zm_im,
                            torch.sqrt(e_re * e_re + e_im * e_im),
                            torch.sqrt(i_re * i_re + i_im * i_im) / s], -1)


class RecordSummary(nn.Module):
    """The domain gate's features of a record, ``(batch, 3)``: probe level |E_H| (mV),
    whisking amplitude of u_L (µm), and log10 of the mean |I_H| (A)."""

    def __init__(self, frames: ProbeFrames) -> None:
        super().__init__()
        self.frames = frames

    def forward(self, e: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        f = self.frames(e, i)
        u = f[..., 0] * 1e6
        return torch.stack([1e3 * f[..., 3].mean(-1), (u.amax(-1) - u.amin(-1)) / 2,
                            torch.log10(f[..., 4].mean(-1))], -1)


class CausalConv(nn.Module):
    """A causal dilated 1-D convolution: output frame t sees input frames ``<= t``."""

    def __init__(self, c_in: int, c_out: int, kernel: int, dilation: int) -> None:
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.conv = nn.Conv1d(c_in, c_out, kernel, dilation=dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(fn.pad(x, (self.pad, 0)))


class OnsetNet(nn.Module):
    """Frames -> (gap m, sigma m, contact probability per frame, onset and detachment margins
    per frame m); see the module docstring.

    Args:
        frames: the feature layer.
        scale: ``(mean, std)`` of the 5 frame features over the training data, ``(2, 5)``.
        amp: the whisking amplitude, m (the offsets' unit).
        reach_per_volt: the calibrated free tip's probe amplitude per probe volt,
            ``1/(ωH |t12|)``, m/V.
        onset_phase: where in its frame a contact starts, from the frame's centre, in
            frames (the onset reach is moved there along u_L's last step).
        channels, dilations, kernel: the temporal convolution.
    """

    HEADS = 8
    """Per frame: contact logit; vote, estimate, log std of g; vote, estimate of the onset
    level; vote, estimate of the detachment level."""

    def __init__(self, frames: ProbeFrames, scale: torch.Tensor, amp: float,
                 reach_per_volt: float, onset_phase: float, channels: int,
                 dilations: tuple[int, ...], kernel: int = 3) -> None:
        super().__init__()
        self.frames = frames
        self.register_buffer("mean", scale[0].float().clone())
        self.register_buffer("std", scale[1].float().clone())
        self.amp = float(amp)
        self.reach_per_volt = float(reach_per_volt)
        self.register_buffer("onset_phase", torch.tensor(float(onset_phase)))
        layers, c_in = [], 6
        for d in dilations:
            layers += [CausalConv(c_in, channels, kernel, d), nn.GELU()]
            c_in = channels
        self.body = nn.Sequential(*layers)
        self.head = nn.Conv1d(channels, self.HEADS, 1)

    def steps(self, f: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
        """u_L's step from the frame before (m), ``(batch, n)``, given the u_L of the frame
        before the first, ``(batch, 1)``."""
        u = torch.cat([previous, f[..., 0]], 1)
        return u[:, 1:] - u[:, :-1]

    def reach(self, f: torch.Tensor) -> torch.Tensor:
        """The free tip's reach on the probe peaks, ``u_L + |u_H|`` (m), ``(batch, n)``."""
        return f[..., 0] + self.reach_per_volt * f[..., 3]

    def per_frame(self, e: torch.Tensor, i: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per frame, each ``(batch, n_frames)``: ``contact`` logit, ``vote``/``est``/
        ``log_sd`` of g (m), ``vote_on``/``est_on`` and ``vote_off``/``est_off`` of the reach
        levels (m), ``reach`` (m) and ``reach_on`` (on the probe peak where contacts start)."""
        f = self.frames(e, i)
        return self.split(f, self.steps(f, f[:, :1, 0]))

    def split(self, f: torch.Tensor, du: torch.Tensor) -> dict[str, torch.Tensor]:
        """The heads of frames ``f`` ``(batch, n, 5)`` with u_L's steps ``du`` (m)."""
        return self.outputs(self.head(self.body(self.inputs(f, du))), f, du)

    def inputs(self, f: torch.Tensor, du: torch.Tensor) -> torch.Tensor:
        """The convolution's input ``(batch, 6, n)``: normalised frames and u_L's step."""
        x = (f - self.mean) / self.std
        return torch.cat([x, (du / self.std[0])[..., None] * 10.0], -1).transpose(1, 2)

    def reaches(self, f: torch.Tensor, du: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The reach at each frame's centre and on the probe peak where contacts start
        (moved along u_L's last step), m, each ``(batch, n)``."""
        reach = self.reach(f)
        return reach, reach + self.onset_phase * du

    def outputs(self, h: torch.Tensor, f: torch.Tensor, du: torch.Tensor
                ) -> dict[str, torch.Tensor]:
        """The per-frame quantities (see :meth:`per_frame`) from the heads ``(batch, 8, n)``."""
        u = f[..., 0]
        reach, reach_on = self.reaches(f, du)
        return {"contact": h[:, 0], "vote": h[:, 1], "est": u + self.amp * h[:, 2],
                "log_sd": h[:, 3], "vote_on": h[:, 4], "est_on": u + self.amp * h[:, 5],
                "vote_off": h[:, 6], "est_off": u + self.amp * h[:, 7], "reach": reach,
                "reach_on": reach_on}

    def pooled(self, p: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """``(g, sd, onset level, detachment level)``, m, each ``(batch,)``."""
        w = torch.softmax(p["vote"], -1)
        g = (w * p["est"]).sum(-1)
        var = (w * torch.exp(2 * p["log_sd"])).sum(-1) * self.amp**2
        on = (torch.softmax(p["vote_on"], -1) * p["est_on"]).sum(-1)
        off = (torch.softmax(p["vote_off"], -1) * p["est_off"]).sum(-1)
        return g, torch.sqrt(var), on, off

    def forward(self, e: torch.Tensor, i: torch.Tensor) -> tuple[torch.Tensor, ...]:
        p = self.per_frame(e, i)
        g, sd, on, off = self.pooled(p)
        prob = torch.sigmoid(p["contact"])
        gap, sd, on_margin, off_margin = answer(g, sd, prob.amax(-1), p["reach_on"].amax(-1),
                                                p, on, off)
        return gap, sd, prob, on_margin, off_margin


def answer(g, sd, top, reach_top, p: dict, on, off) -> tuple[torch.Tensor, ...]:
    """The location and margins from the pooled quantities (``(batch,)``, m), the record's
    highest contact probability ``top`` and highest reach on a probe peak ``reach_top`` (m)
    (each ``(batch,)``), and the per-frame reaches ``p["reach_on"]`` and ``p["reach"]`` (m,
    ``(batch, n)``): ``(gap, sigma, onset_margin, detach_margin)``.

    One decision gives the wall and the contacts: a record touches a wall where a frame's
    contact probability passes 0.5 and the free tip's reach passes the onset level; then
    the onset margin is >= 0 on at least one frame (a contact interval,
    :func:`wtml.runtime.onset.contacts_from`) and g and σ are reported. Otherwise gap and
    σ are NaN ("no wall": free whisking) and the margins -1 m (no interval)."""
    touched = (top > 0.5) & (reach_top >= on)
    nan, never = torch.full_like(g, float("nan")), torch.full_like(p["reach"], -1.0)
    return (torch.where(touched, g, nan), torch.where(touched, sd, nan),
            torch.where(touched[:, None], p["reach_on"] - on[:, None], never),
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


def level_brackets(targets: torch.Tensor, reach_on: torch.Tensor, reach: torch.Tensor,
                   frame_s: float, max_contacts: int
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where the onset and detachment levels must lie for the timing rule to pick each true
    contact's frames: ``(low, high)`` of the onset level (on ``reach_on``), then of the
    detachment level (on ``reach``), each ``(batch, max_contacts)`` m, NaN where a record has
    fewer contacts.

    A contact starting in frame k needs ``reach_on[k-1] < level <= reach_on[k]``; one ending
    in frame j needs ``reach[j+1] < level <= reach[j]``.
    """
    n = reach.shape[1]

    def at(r: torch.Tensor, times: torch.Tensor, shift: int) -> torch.Tensor:
        k = torch.floor(torch.nan_to_num(times) / frame_s).long() + shift
        v = r.gather(1, k.clamp(0, n - 1))
        return torch.where(torch.isfinite(times), v, torch.full_like(v, float("nan")))

    on = targets[:, 1:1 + max_contacts]
    off = targets[:, 1 + max_contacts:1 + 2 * max_contacts]
    return at(reach_on, on, -1), at(reach_on, on, 0), at(reach, off, 1), at(reach, off, 0)


def onset_bias(level: np.ndarray, low: np.ndarray, high: np.ndarray,
               span: float = 0.1e-6) -> float:
    """The bias c (m) for which ``level - c`` falls inside the most onset brackets
    ``(low, high]`` (each ``(n, max_contacts)``; ``level`` ``(n, 1)``: g/s per record),
    searched over ±``span`` in 1 nm steps; the middle of the best plateau."""
    ok = np.isfinite(low) & np.isfinite(level)
    c = np.arange(-span, span + 0.5e-9, 1e-9)
    inside = [np.mean(((level - x > low) & (level - x <= high))[ok]) if ok.any() else 0.0
              for x in c]
    best = np.flatnonzero(np.isclose(inside, max(inside)))
    return float(np.median(c[best]))


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
        location_weight: weight of the location's Gaussian NLL.
        timing_weight: weight of the reach levels' log-cosh loss (:data:`LEVEL_SCALE`): the
            onset level towards g/s less :func:`onset_bias`, the detachment level towards the
            middle of its brackets (:func:`level_brackets`).
        lr, weight_decay: as every decoder.
    """

    def __init__(self, channels: int = 32, dilations: list[int] | None = None,
                 contact_weight: float = 30.0, location_weight: float = 1.0,
                 timing_weight: float = 1.0, lr: float = 3e-3,
                 weight_decay: float = 1e-5) -> None:
        super().__init__(lr, weight_decay)
        dilations = [1, 2, 4, 8, 16] if dilations is None else list(dilations)
        if not 1 <= channels <= 1024:
            raise ConfigError(f"model.channels must be in [1, 1024], got {channels!r}")
        if not dilations or any(not 1 <= d <= 4096 for d in dilations):
            raise ConfigError(f"model.dilations must be a non-empty list of values in "
                              f"[1, 4096], got {dilations!r}")
        check_positive("model.contact_weight", contact_weight, 1e6)
        check_positive("model.location_weight", location_weight, 1e6)
        check_positive("model.timing_weight", timing_weight, 1e6)
        self.save_hyperparameters()
        self.register_buffer("offsets", torch.zeros(2))
        self.register_buffer("onset_bias", torch.zeros(()))  # m, :func:`onset_bias`

    @staticmethod
    def _probe_t(scene) -> np.ndarray:
        wh = 2 * np.pi * scene.drive.probe_hz
        return scene.transducer().transduction_matrix(np.array([wh]))[0]

    def _frames(self, scene) -> ProbeFrames:
        hue0 = scene.transducer().static_tip_displacement_per_volt()
        return ProbeFrames(frame_period(scene), self._probe_t(scene), hue0)

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        return RecordSummary(self._frames(scene)), 3

    def _make(self, scene, scale: torch.Tensor, onset_phase: float = 0.0) -> OnsetNet:
        h = self.hparams
        reach = 1 / (2 * np.pi * scene.drive.probe_hz * abs(self._probe_t(scene)[0, 1]))
        return OnsetNet(self._frames(scene), scale, scene.whisk_amplitude_m(), reach,
                        onset_phase, h.channels, tuple(h.dilations))

    def build_net(self, scene, e, i, targets) -> nn.Module:
        frames = self._frames(scene)
        with torch.no_grad():
            f = torch.cat([frames(e[s:s + 64], i[s:s + 64]) for s in range(0, len(e), 64)])
        # a feature the data hold nearly constant (the probe level) is scaled no finer than
        # float32 resolves it, or rounding differences between graphs would drive the net
        floor = RESOLUTION * f.abs().amax((0, 1))
        scale = torch.stack([f.mean((0, 1)), torch.maximum(f.std((0, 1)), floor)])
        frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
        self.offsets.copy_(torch.tensor(edge_offsets(targets.numpy(), frame_s,
                                                     scene.max_contacts)))
        self._frame_s, self._max_contacts = frame_s, scene.max_contacts
        net = self._make(scene, scale, float(self.offsets[0]) / frame_s - 0.5)
        with torch.no_grad():
            reach, reach_on = net.reaches(f, net.steps(f, f[:, :1, 0]))
            lo, hi, _, _ = level_brackets(targets, reach_on, reach, frame_s,
                                          scene.max_contacts)
        level = (targets[:, :1] / targets[:, -1:]).numpy()  # g/s
        self.onset_bias.fill_(onset_bias(level, lo.numpy(), hi.numpy()))
        return net

    def net_shape(self) -> dict:
        return {}

    def build_from_checkpoint(self, shape: dict) -> None:
        from wtml.scenes import scene_from_dict

        scene = scene_from_dict(self.scene)
        self.net = self._make(scene, torch.ones(2, 5))
        self._frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
        self._max_contacts = scene.max_contacts

    def loss(self, batch) -> torch.Tensor:
        e, i, targets = batch
        p = self.net.per_frame(e, i)
        labels = frame_labels(targets, p["contact"].shape[1], self._frame_s,
                              self._max_contacts)
        bce = self.hparams.contact_weight * fn.binary_cross_entropy_with_logits(
            p["contact"], labels)
        g, sd, on, off = self.net.pooled(p)
        has = torch.isfinite(targets[:, 0])
        if not has.any():
            return bce
        amp = self.net.amp
        z = (g[has] - targets[has, 0]) / amp
        s = sd[has] / amp
        nll = (0.5 * (z / s) ** 2 + torch.log(s)).mean()
        _, _, lo_off, hi_off = level_brackets(targets, p["reach_on"], p["reach"],
                                              self._frame_s, self._max_contacts)
        # the onset level: the wall as the calibrated model sees it, g/s, less the bias;
        # the detachment level: the middle of its brackets (the two whisks' overlap)
        level_on = targets[:, 0] / targets[:, -1] - self.onset_bias
        timing = torch.cat([on - level_on, off - torch.nanmean((lo_off + hi_off) / 2, 1)])
        timing = timing / (LEVEL_SCALE * amp)
        timing = timing[torch.isfinite(timing)].abs()
        timing = (timing + torch.log1p(torch.exp(-2 * timing)) - np.log(2.0)).mean()  # log cosh
        return bce + self.hparams.location_weight * nll + self.hparams.timing_weight * timing


def frame_period(scene) -> int:
    """Samples per probe period; the scene's rate must be a whole multiple of the probe."""
    ratio = scene.acquisition.sample_rate_hz / scene.drive.probe_hz
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ConfigError(f"acquisition.sample_rate_hz {scene.acquisition.sample_rate_hz:g} "
                          f"must be a whole multiple of drive.probe_hz {scene.drive.probe_hz:g} "
                          "for the onset decoder's probe frames")
    return int(round(ratio))
