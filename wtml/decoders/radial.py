"""Radial-location decoders: Ze at the touch tone(s) and the device's free reference ->
distance of the contact from the tip.

Every radial decoder takes four inputs, each ``(batch, n_freq)`` float32 Ω: ``ze_re, ze_im``
(the measurement with the contact) and ``ref_re, ref_im`` (the free, untouched whisker's Ze
at the same tones, measured when the device is set up: issue 21). A built device is not the
preset; the reference is what tells a decoder which device it is on. :class:`RadialNet` reads
(:class:`ReferenceParts`) the contact's change against the reference, the ratio
``ze / ref - 1`` per frequency, and the reference itself, standardises them with buffers and
maps them through an MLP to the standardised distance, and optionally to a predicted standard
deviation (a Gaussian negative log-likelihood head). The thesis's decoder is a RadialNet with
``reference: false``: a 2-10-1 sigmoid MLP on (Re Ze, Im Ze) at 420 Hz, which knows only the
nominal device (``configs/radial_thesis.yaml``).

Ours (``configs/radial.yaml``) is :class:`RefinedRadialNet`, two stages in one graph. Why: a
plain MLP stalls near 1e-3 of the range (3.1–3.4 µm on 3.2 mm, whatever its width, depth,
data or input map), the usual precision of a trained MLP, while the noise allows ~0.4 µm; the
contact stiffness moves Ze by ~0.5 % and the noise is 2e-5, so reading d needs Ze resolved to
~1e-5 of its range. The first stage is a RadialNet (the coarse d0). The second reads the
scene's forward model of the nominal device as a ratio to its free Ze, tabulated in d at the
reference stiffness (:class:`HermiteTable`, cubic Hermite, float32), and turns the
measurement's ratio ``r = ze / ref`` into a residual that is small and nearly linear in the
unknowns: per frequency ``p = (r - R(d0)) / (dR/dd)(d0)``, a complex distance in m (its real
part is d - d0 plus the stiffness's and the device's share). An MLP maps (p, d0, the
reference) to the correction d - d0 and, with the uncertainty head, its std, trained by
Gaussian
NLL, which lets it spend its precision where the bound is tight (measured: the worst
800 µm range at 1.8× the bound with MSE, 1.3× with NLL). It is a learned
Gauss–Newton step: the learned start replaces the inversion's grid search, the learned step
its stiffness model. The coarse stage trains first, then the refiner with the coarse stage
frozen (``RadialDecoder.coarse_epochs``).
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np
import torch
from torch import nn

from wtml.decoders.base import ConfigError, DecoderModule, check_widths
from wtml.decoders.checkpoint import load_module
from wtml.decoders.layers import HermiteTable
from wtml.decoders.mlp import MLP

ACTIVATIONS = {"sigmoid": nn.Sigmoid, "silu": nn.SiLU}


class ReferenceParts(nn.Module):
    """The radial input features: the contact's change against the free reference,
    ``ze / ref - 1`` (Re, Im), and the reference ``(Re ref, Im ref)``, each per frequency:
    ``(ze_re, ze_im, ref_re, ref_im)`` ``(batch, n_freq)`` -> ``(batch, 4 n_freq)``. With
    ``reference=False``, ``(Re Ze, Im Ze)`` only (the thesis's inputs; the reference is
    ignored); with ``device=False``, the ratio only, ``(batch, 2 n_freq)``: a decoder trained
    on one device (the shipped scene), whose references differ only by their noise (as
    inputs, 2 n_freq features of pure noise: measured, they took its worst 800 µm range of d
    from 1.3× to 1.8× the Cramér–Rao bound). Its domain gate still reads the reference
    (:class:`GateParts`), so another device is flagged."""

    def __init__(self, reference: bool = True, device: bool = True) -> None:
        super().__init__()
        self.reference, self.device = reference, device

    @staticmethod
    def width(n_freq: int, reference: bool = True, device: bool = True) -> int:
        """Number of features for ``n_freq`` frequencies."""
        return (4 if reference and device else 2) * n_freq

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, ref_re: torch.Tensor,
                ref_im: torch.Tensor) -> torch.Tensor:
        if not self.reference:
            return torch.cat([ze_re, ze_im], -1)
        r_re, r_im = ratio(ze_re, ze_im, ref_re, ref_im)
        if not self.device:
            return torch.cat([r_re - 1, r_im], -1)
        return torch.cat([r_re - 1, r_im, ref_re, ref_im], -1)


class GateParts(nn.Module):
    """The radial domain gate's features: :class:`ReferenceParts`' ratio ``ze / ref - 1``
    (Re, Im) and ``log |ze / ref|`` (a measurement scaled against its reference leaves the
    box of those however the spread widens the ellipsoid), the reference's deviation from
    the preset's free Ze ``u = ref / free - 1`` (Re, Im), and every product ``u_i u_j``
    (i <= j) of those 2 n_freq deviations:
    ``(ze_re, ze_im, ref_re, ref_im)`` ``(batch, n_freq)`` -> ``(batch, n_feat(n_freq))``.

    Why the products: a device drawn from the spread moves its free Ze by O(10 %) near the
    resonance, along a curved set of dimension ~9 (one per device parameter) in the 2 n_freq
    real numbers. An ellipsoid on linear features holds that set's whole hull: measured on
    the shipped scene, it passed 62–69 % of measurements and references with Re Ze × 1.5 and
    every device with its structural loss doubled. The whitened quadratic terms hold the
    set's curvature (near-null directions are near-satisfied quadratic constraints), and
    flag both (scores ≥ 3 and ≥ 6) at the same false-alarm rate on new devices.

    With ``device=False`` (a scene of one device, the preset's): the ratio ``ze / ref - 1``
    (Re, Im), ``log |ze / ref|`` and one feature for the reference, ``Σ |u|²``, ``(batch,
    3 n_freq + 1)``. There
    the deviations are the reference's noise alone, and 2 n_freq (2 n_freq + 3) / 2 features
    of pure noise would dilute the whitened distance of the contact's own features: measured
    on the shipped scene, such a gate passed 2 % of the contacts 3300–3330 µm from the tip
    (trained: 0–3200 µm); the sum keeps another device far outside (|u| ~ 1e-2 against the
    noise's 2e-6).

    Args:
        free: the preset's free Ze at the scene's frequencies, complex ``(n_freq,)`` Ω.
        device: the scene draws its devices from a spread.
    """

    def __init__(self, free: np.ndarray, device: bool = True) -> None:
        super().__init__()
        self.device = device
        free = np.asarray(free, dtype=complex)
        self.n_freq = len(free)
        self.register_buffer("free_re", torch.tensor(free.real, dtype=torch.float32))
        self.register_buffer("free_im", torch.tensor(free.imag, dtype=torch.float32))
        i, j = torch.triu_indices(2 * self.n_freq, 2 * self.n_freq)
        self.register_buffer("pair_i", i)
        self.register_buffer("pair_j", j)
        self.parts = ReferenceParts()

    @staticmethod
    def n_feat(n_freq: int, device: bool = True) -> int:
        """Number of features for ``n_freq`` frequencies: 5 n + 2n (2n + 1) / 2 (without
        ``device``: 3 n + 1)."""
        if not device:
            return 3 * n_freq + 1
        return 5 * n_freq + n_freq * (2 * n_freq + 1)

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, ref_re: torch.Tensor,
                ref_im: torch.Tensor) -> torch.Tensor:
        r_re, r_im = ratio(ze_re, ze_im, ref_re, ref_im)
        # u = (ref - free) × (1 / free): the reciprocal of the constant folds in the graph, and
        # the difference comes before any rounding of ref's size (u is ~1e-6 on one device)
        den = self.free_re * self.free_re + self.free_im * self.free_im
        w_re, w_im = self.free_re / den, -self.free_im / den
        d_re, d_im = ref_re - self.free_re, ref_im - self.free_im
        u = torch.cat([d_re * w_re - d_im * w_im, d_re * w_im + d_im * w_re], -1)
        log_r = 0.5 * torch.log(r_re * r_re + r_im * r_im)
        if not self.device:
            return torch.cat([r_re - 1, r_im, log_r, (u * u).sum(-1, keepdim=True)], -1)
        return torch.cat([r_re - 1, r_im, log_r, u, u[:, self.pair_i] * u[:, self.pair_j]],
                         -1)


def ratio(a_re: torch.Tensor, a_im: torch.Tensor, b_re: torch.Tensor, b_im: torch.Tensor
          ) -> tuple[torch.Tensor, torch.Tensor]:
    """``a / b`` for complex numbers given as real and imaginary parts."""
    den = b_re * b_re + b_im * b_im
    return (a_re * b_re + a_im * b_im) / den, (a_im * b_re - a_re * b_im) / den


class RadialNet(nn.Module):
    """(Ze, reference) -> (distance in m, its predicted std in m).

    Args:
        n_freq: frequencies of the input.
        hidden: hidden widths.
        activation: ``"sigmoid"`` (the thesis) or ``"silu"``.
        uncertainty: add the std head (otherwise the std output is 0).
        used_frequencies: use only the first this many frequencies (the thesis decoder: 1,
            the 420 Hz tone); all by default.
        reference: read the reference (:class:`ReferenceParts`); ``False``: Ze alone.
        device: read the reference's own values too, not only the ratio to it
            (:class:`ReferenceParts`): for a decoder trained over a device spread.

    Forward: ``ze_re, ze_im, ref_re, ref_im`` ``(batch, n_freq)`` float32 Ω ->
    ``distance (batch,)``, ``sigma (batch,)``.
    """

    def __init__(self, n_freq: int, hidden: list[int], activation: str = "silu",
                 uncertainty: bool = True, used_frequencies: int | None = None,
                 reference: bool = True, device: bool = True) -> None:
        super().__init__()
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, "
                             f"got {activation!r}")
        self.n_freq = n_freq
        self.used = n_freq if used_frequencies is None else used_frequencies
        if not 1 <= self.used <= n_freq:
            raise ValueError(f"used_frequencies must be in [1, {n_freq}], got {self.used}")
        self.uncertainty = uncertainty
        self.parts = ReferenceParts(reference, device)
        self.device = device
        width = ReferenceParts.width(self.used, reference, device)
        self.mlp = MLP(width, hidden, 2 if uncertainty else 1,
                       activation=ACTIVATIONS[activation])
        self.register_buffer("feature_mean", torch.zeros(width))
        self.register_buffer("feature_std", torch.ones(width))
        self.register_buffer("target_mean", torch.zeros(1))
        self.register_buffer("target_std", torch.ones(1))

    def features(self, *inputs: torch.Tensor) -> torch.Tensor:
        """:class:`ReferenceParts` of the used frequencies, ``(batch, 2 or 4 × used)``."""
        if self.used < self.n_freq:
            inputs = tuple(x[:, :self.used] for x in inputs)
        return self.parts(*inputs)  # unsliced, the graph shares its ratio with the gate's

    def forward_normalized(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Standardised distance and, with the head, log std: shape ``(batch, 1 or 2)``."""
        return self.mlp((self.features(*inputs) - self.feature_mean) / self.feature_std)

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, ref_re: torch.Tensor,
                ref_im: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        y = self.forward_normalized(ze_re, ze_im, ref_re, ref_im)
        distance = y[:, 0] * self.target_std + self.target_mean
        if self.uncertainty:
            return distance, torch.exp(y[:, 1]) * self.target_std
        return distance, torch.zeros_like(distance)

    def target(self, distance: torch.Tensor) -> torch.Tensor:
        """What the MLP learns: the standardised distance."""
        return (distance - self.target_mean) / self.target_std

    @torch.no_grad()
    def fit_normalization(self, *tensors: torch.Tensor) -> None:
        """Feature and target statistics from the training ``(*inputs, targets)``."""
        *inputs, targets = tensors
        x = self.features(*inputs)
        self.feature_mean.copy_(x.mean(0))
        self.feature_std.copy_(x.std(0).clamp_min(1e-12))
        self.target_mean.copy_(targets.mean(0))
        self.target_std.copy_(targets.std(0).clamp_min(1e-12))


TABLE_POINTS = 20000
"""The most points :func:`contact_table` computes (each a beam-model Ze at every frequency):
a 0.16 µm step over the radial scene's 3.2 mm (about 10 s; the 5 µm default takes 640 points
and 26 ms), where the cubic interpolation's error (2.5e-7 at 5 µm, falling as the step's
fourth power) is far below float32's resolution."""


def contact_table(scene, step: float = 5e-6, h: float = 1e-8) -> HermiteTable:
    """The nominal device's noise-free ratio ``R(d) = Ze(d) / Ze_free`` at the scene's
    reference stiffness (the geometric mean of its range) and dR/dd (central differences of
    ``h`` m, one-sided at d = 0), on a grid of ``step`` m over ``scene.distance_range_m()``.
    At 5 µm the cubic interpolation is within 2.5e-7 of the model on the default scene
    (noise 2e-5)."""
    lo, hi = scene.distance_range_m()
    grid = np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / step)) + 1))
    k = np.full_like(grid, scene.reference_stiffness())
    tr = scene.transducer()
    free = scene.free_ze(tr)
    below = np.maximum(grid - h, 0.0)
    slopes = ((scene.ze_of(grid + h, k, tr) - scene.ze_of(below, k, tr))
              / (grid + h - below)[:, None])
    return HermiteTable(lo, grid[1] - grid[0], scene.ze_of(grid, k, tr) / free, slopes / free)


class RefinedRadialNet(nn.Module):
    """Coarse RadialNet, then a learned Gauss–Newton step on the tabulated forward model
    (module docstring): (Ze, reference) -> (distance in m, its predicted std in m).

    Args:
        n_freq: frequencies of the input.
        hidden, refine_hidden: hidden widths of the coarse and the refining MLP.
        table: the scene's :func:`contact_table`.
        scale: the correction's unit in m (about the coarse stage's RMSE).
        activation, uncertainty: as for :class:`RadialNet` (the std head is on the refiner).
        device: both stages also read the reference's own values (a decoder trained over a
            device spread); else the coarse stage reads the ratio ``ze / ref`` and the
            refiner ``(p, d0)`` only (:class:`ReferenceParts`).

    Forward: ``ze_re, ze_im, ref_re, ref_im`` ``(batch, n_freq)`` float32 Ω ->
    ``distance (batch,)``, ``sigma (batch,)``.
    """

    def __init__(self, n_freq: int, hidden: list[int], refine_hidden: list[int],
                 table: HermiteTable, scale: float, activation: str = "silu",
                 uncertainty: bool = True, device: bool = True) -> None:
        super().__init__()
        if table.n_col != n_freq:
            raise ValueError(f"the table has {table.n_col} frequencies, the input {n_freq}")
        if not scale > 0:
            raise ValueError(f"refine scale must be > 0 m, got {scale}")
        self.n_freq, self.uncertainty, self.scale = n_freq, uncertainty, float(scale)
        self.clip = 10.0  # standardised residuals beyond ±clip are clamped (a lost start)
        self.coarse = RadialNet(n_freq, hidden, activation, uncertainty=False, device=device)
        self.table, self.device = table, device
        width = ReferenceParts.width(n_freq, True, device) + 1
        self.refine = MLP(width, refine_hidden, 2 if uncertainty else 1,
                          activation=ACTIVATIONS[activation])
        self.register_buffer("refine_mean", torch.zeros(width))
        self.register_buffer("refine_std", torch.ones(width))

    def coarse_distance(self, *inputs: torch.Tensor) -> torch.Tensor:
        """The first stage's d0 in m, ``(batch,)``."""
        y = self.coarse.forward_normalized(*inputs)[:, 0]
        return y * self.coarse.target_std + self.coarse.target_mean

    def residual(self, ze_re: torch.Tensor, ze_im: torch.Tensor, ref_re: torch.Tensor,
                 ref_im: torch.Tensor, d0: torch.Tensor) -> torch.Tensor:
        """``(Re p, Im p, d0, Re ref, Im ref)`` (m, m, m, Ω, Ω), ``(batch, 4 n_freq + 1)``
        (without ``device``: ``(Re p, Im p, d0)``): p per frequency as in the module
        docstring."""
        f_re, f_im, g_re, g_im = self.table(d0)
        # p = (ze/ref - R) / R': the ratio's few roundings (~2e-7 of it; the noise is 2e-5),
        # and ze/ref is the coarse stage's ratio, which the graph computes once
        r_re, r_im = ratio(ze_re, ze_im, ref_re, ref_im)
        p_re, p_im = ratio(r_re - f_re, r_im - f_im, g_re, g_im)
        if not self.device:
            return torch.cat([p_re, p_im, d0[:, None]], -1)
        return torch.cat([p_re, p_im, d0[:, None], ref_re, ref_im], -1)

    def refine_normalized(self, ze_re: torch.Tensor, ze_im: torch.Tensor,
                          ref_re: torch.Tensor, ref_im: torch.Tensor, d0: torch.Tensor
                          ) -> torch.Tensor:
        """The correction in units of ``scale`` and, with the head, its log std:
        ``(batch, 1 or 2)``."""
        x = (self.residual(ze_re, ze_im, ref_re, ref_im, d0) - self.refine_mean) \
            / self.refine_std
        return self.refine(x.clamp(-self.clip, self.clip))

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, ref_re: torch.Tensor,
                ref_im: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        inputs = (ze_re, ze_im, ref_re, ref_im)
        d0 = self.coarse_distance(*inputs)
        y = self.refine_normalized(*inputs, d0)
        distance = d0 + y[:, 0] * self.scale
        if self.uncertainty:
            return distance, torch.exp(y[:, 1]) * self.scale
        return distance, torch.zeros_like(distance)

    @torch.no_grad()
    def fit_normalization(self, *tensors: torch.Tensor, seed: int = 0) -> None:
        """Both stages' statistics from the training ``(*inputs, targets)``; the refiner's at
        starts ``d0 = d + N(0, scale²)``, the coarse stage's errors it is built for."""
        *inputs, targets = tensors
        self.coarse.fit_normalization(*tensors)
        noise = torch.randn(len(targets), generator=torch.Generator().manual_seed(seed))
        x = self.residual(*inputs, targets[:, 0] + self.scale * noise)
        self.refine_mean.copy_(x.mean(0))
        self.refine_std.copy_(x.std(0).clamp_min(1e-12))


def fit_loss(out: torch.Tensor, target: torch.Tensor, uncertainty: bool) -> torch.Tensor:
    """MSE of ``out[:, 0]`` on the normalised target, or Gaussian NLL with ``out[:, 1]`` the
    log std."""
    if not uncertainty:
        return nn.functional.mse_loss(out[:, 0], target)
    return nn.functional.gaussian_nll_loss(out[:, 0], target, torch.exp(2 * out[:, 1]))


def one_cycle(step: int, start: int, end: int, warmup: float = 0.3) -> float:
    """Learning-rate factor of a one-cycle schedule over steps ``[start, end)`` and 0
    outside: cosine from 1/25 up to 1 over the first ``warmup`` of it, then cosine down to
    1/25e4 (the shape of ``torch.optim.lr_scheduler.OneCycleLR``'s defaults)."""
    if not start <= step < end:
        return 0.0
    x, peak = (step - start) / (end - start), warmup
    lo, hi = (1 / 25, 1.0) if x < peak else (1.0, 1 / 25e4)
    phase = x / peak if x < peak else (x - peak) / (1 - peak)
    return hi + (lo - hi) * (1 + math.cos(math.pi * phase)) / 2


class RadialDecoder(DecoderModule):
    """Trains :class:`RadialNet`: MSE, or Gaussian NLL with the uncertainty head.

    Args:
        hidden: hidden widths ([10] for the thesis's 2-10-1; the coarse stage with
            ``refine_hidden``).
        activation: ``"sigmoid"`` or ``"silu"``.
        uncertainty: predict a std as well.
        used_frequencies: only the first this many of the scene's frequencies (default all;
            a plain RadialNet only).
        refine_hidden: hidden widths of the refining stage; ``None`` (default): a plain
            RadialNet, otherwise a :class:`RefinedRadialNet`.
        table_step_um: grid step of the forward-model table, µm.
        refine_scale_um: the correction's unit, µm (about the coarse stage's RMSE).
        coarse_epochs: with ``refine_hidden``, the epochs that train the coarse stage alone;
            the refiner trains in the rest with the coarse stage frozen. Each has its own
            one-cycle schedule. Measured: trained together instead (the refiner chasing a
            moving start), the worst 800 µm range of d ends at 3.3× the bound, against 1.3× in
            turn (128-wide stages).
        lr, weight_decay: optimiser.
        reference: read the free reference (default); ``False``: Ze alone, the nominal device
            assumed (the thesis's decoder; a plain RadialNet only).
        optimizer: ``"adamw"`` (one-cycle schedule) or ``"lbfgs"``: full-batch L-BFGS with a
            strong-Wolfe line search, up to 50 iterations per step (``lr`` its initial step,
            1 as a rule; no weight decay), a second-order method like the Levenberg–Marquardt
            the thesis trained its 2-10-1 net with; give it the whole training split as one
            batch. A plain RadialNet only. Measured on the radial scene's 2-10-1: 3.5 µm in 5 s
            against 15.3 µm after 7000 AdamW steps (27 s).
        device_inputs: read the reference's own values as well as the ratio ``ze / ref``
            (:class:`ReferenceParts`); ``None`` (default): where the scene's spread has
            tolerance bands (``DeviceSpread.tolerances``), not over a fitted device's
            posterior alone (``spread.posterior``), whose references differ by little more
            than their noise: there, reading them took the decoder from 0.52 to 1.26 µm on
            the hidden device of ``wtml bench device``.
    """

    TASK = "radial"

    def __init__(self, hidden: list[int] | None = None, activation: str = "silu",
                 uncertainty: bool = True, used_frequencies: int | None = None,
                 refine_hidden: list[int] | None = None, table_step_um: float = 5.0,
                 refine_scale_um: float = 3.0, coarse_epochs: int = 20, lr: float = 3e-3,
                 weight_decay: float = 0.0, optimizer: str = "adamw", reference: bool = True,
                 device_inputs: bool | None = None) -> None:
        super().__init__(lr, weight_decay)
        self.save_hyperparameters()
        if optimizer not in ("adamw", "lbfgs"):
            raise ConfigError(f"model.optimizer must be 'adamw' or 'lbfgs', got {optimizer!r}")
        if optimizer == "lbfgs" and refine_hidden is not None:
            raise ConfigError("model.optimizer 'lbfgs' trains a plain RadialNet only; the "
                              "refined decoder trains its stages in turn with 'adamw'")
        if optimizer == "lbfgs" and weight_decay:
            raise ConfigError(f"model.weight_decay must be 0 with model.optimizer 'lbfgs' (it "
                              f"has none), got {weight_decay!r}")
        self.hidden = list(hidden or [64, 64])
        check_widths("model.hidden", self.hidden)
        if refine_hidden is not None:
            check_widths("model.refine_hidden", refine_hidden)
        if refine_hidden is not None and not reference:
            raise ConfigError("model.reference false applies to a plain RadialNet only; the "
                              "refined decoder reads the reference")
        if refine_hidden is not None and used_frequencies is not None:
            raise ConfigError("used_frequencies applies to a plain RadialNet only; "
                             "the refined decoder reads every frequency of its table")
        if device_inputs is not None and not isinstance(device_inputs, bool):
            raise ConfigError(f"model.device_inputs must be true, false or null (from the "
                              f"scene's spread), got {device_inputs!r}")
        for name, value in (("table_step_um", table_step_um),
                            ("refine_scale_um", refine_scale_um)):
            if isinstance(value, bool) or not isinstance(value, int | float) \
                    or not 0 < value < 1e4:
                raise ConfigError(f"model.{name} must be in (0, 1e4) µm, got {value}")

    def _new(self, n_freq: int, table: HermiteTable | None = None, device: bool = True
             ) -> RadialNet | RefinedRadialNet:
        h = self.hparams
        if h.refine_hidden is None:
            return RadialNet(n_freq, self.hidden, h.activation, h.uncertainty,
                             h.used_frequencies, h.get("reference", True), device)
        return RefinedRadialNet(n_freq, self.hidden, list(h.refine_hidden), table,
                                1e-6 * h.refine_scale_um, h.activation, h.uncertainty, device)

    def build_net(self, scene, *tensors) -> RadialNet | RefinedRadialNet:
        """The net, normalised on the training ``(ze_re, ze_im, ref_re, ref_im, targets)``."""
        table = None
        if self.hparams.refine_hidden is not None:
            if not 0 < self.hparams.coarse_epochs < self.trainer.max_epochs:
                raise ConfigError(f"model.coarse_epochs must be in [1, trainer.max_epochs - 1]"
                                  f" = [1, {self.trainer.max_epochs - 1}], "
                                  f"got {self.hparams.coarse_epochs}")
            lo, hi = scene.distance_range_m()
            finest = 1e6 * (hi - lo) / TABLE_POINTS
            if self.hparams.table_step_um < finest:
                raise ConfigError(
                    f"model.table_step_um must be in [{finest:.3g}, 1e4) µm for this scene (at "
                    f"most {TABLE_POINTS} beam-model points over its {1e6 * (hi - lo):g} µm of "
                    f"distance), got {self.hparams.table_step_um:g}")
            table = contact_table(scene, 1e-6 * self.hparams.table_step_um)
        # the reference's own values are inputs where the scene's devices differ
        device = self.hparams.get("device_inputs")
        net = self._new(tensors[0].shape[1], table,
                        device=scene.spread.tolerances if device is None else device)
        net.fit_normalization(*tensors)
        return net

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        """The contact's change against the reference, the reference's deviation from the
        preset and its products (:class:`GateParts`) at every frequency of the scene: a
        reference far from the trained devices is out of domain, whatever the decoder
        reads."""
        device = not scene.spread.none
        return (GateParts(scene.free_ze(), device),
                GateParts.n_feat(len(scene.excitation.frequencies_hz), device))

    def net_shape(self) -> dict:
        shape = {"n_freq": self.net.n_freq, "device_inputs": self.net.device}
        if isinstance(self.net, RefinedRadialNet):
            t = self.net.table
            shape["table"] = {"x0": t.x0, "step": t.step, "n": t.n}
        return shape

    def build_from_checkpoint(self, shape: dict) -> None:
        table = shape.get("table")
        self.net = self._new(shape["n_freq"], table and HermiteTable.empty(
            table["x0"], table["step"], table["n"], shape["n_freq"]),
            shape.get("device_inputs", True))

    def loss(self, batch) -> torch.Tensor:
        *inputs, target = batch
        net, d = self.net, target[:, 0]
        if isinstance(net, RadialNet):
            return fit_loss(net.forward_normalized(*inputs), net.target(d), net.uncertainty)
        if self.current_epoch < self.hparams.coarse_epochs:
            return fit_loss(net.coarse.forward_normalized(*inputs), net.coarse.target(d),
                            False)
        with torch.no_grad():
            d0 = net.coarse_distance(*inputs)
        return fit_loss(net.refine_normalized(*inputs, d0), (d - d0) / net.scale,
                        net.uncertainty)

    def configure_optimizers(self):
        if self.hparams.optimizer == "lbfgs":
            return torch.optim.LBFGS(self.parameters(), lr=self.hparams.lr, max_iter=50,
                                     history_size=50, line_search_fn="strong_wolfe")
        if isinstance(self.net, RadialNet):
            return super().configure_optimizers()
        h = self.hparams
        opt = torch.optim.AdamW([{"params": self.net.coarse.parameters()},
                                 {"params": self.net.refine.parameters()}],
                                lr=h.lr, weight_decay=h.weight_decay)
        total = self.trainer.estimated_stepping_batches
        split = total * h.coarse_epochs // self.trainer.max_epochs
        phases = [partial(one_cycle, start=0, end=split),
                  partial(one_cycle, start=split, end=total)]
        sched = torch.optim.lr_scheduler.LambdaLR(opt, phases)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


def load_radial_net(checkpoint: str) -> tuple[RadialNet | RefinedRadialNet, dict]:
    """The trained net (eval mode) and its scene mapping."""
    module = load_module(RadialDecoder, checkpoint, "radial")
    return module.net.eval(), module.scene


class TorchRadial:
    """A radial net behind the radial predict interface:
    ``predict(ze, ref) -> {"distance", "sigma"}`` (``ze``, ``ref`` complex ``(n, n_freq)``)."""

    def __init__(self, net: RadialNet | RefinedRadialNet, name: str = "decoder torch") -> None:
        self.net, self.name = net.eval(), name

    @torch.no_grad()
    def predict(self, ze: np.ndarray, ref: np.ndarray) -> dict[str, np.ndarray]:
        parts = [torch.tensor(p, dtype=torch.float32) for z in (np.asarray(ze), np.asarray(ref))
                 for p in (z.real, z.imag)]
        d, s = self.net(*parts)
        return {"distance": d.numpy().astype(float), "sigma": s.numpy().astype(float)}
