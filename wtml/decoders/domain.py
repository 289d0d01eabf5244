"""The trained domain, carried inside every exported graph.

A decoder answers only inside the domain it was trained on. :class:`DomainGate` holds that
domain: the input statistics of the training data (mean, a whitening matrix and the range of
each of the task's input features), a threshold at a stated quantile of the training data's
own scores, and the trained range of each output (the scene's ranges, widened by a margin).
Its score is the larger of two: the squared whitened distance of an input's features from
the training mean over that threshold (an ellipsoid: it catches inputs off the data's
manifold), and how far the input leaves the box of the training features, in units of a 5 %
margin of each feature's span (it catches an extrapolation along the manifold, such as a
viscosity a decade below the range, which the ellipsoid's long axis can hold). ``score <= 1``
inside: for all but about ``1 - quantile`` of the training data. :class:`Gated`
wraps any exported net (decoder or classical path) with it, so the ONNX graph itself returns
``in_domain`` and ``domain_score`` beside the task's outputs, and sets every predicted
uncertainty to NaN out of domain (an uncertainty must not shrink where the net was never
trained).

A task declares only two things: the feature layer (``DecoderModule.domain_features``) and
its outputs' ranges (``scene.output_ranges()``, ``wtml.interface.OutputRange``). The gate
is fitted in ``DecoderModule.setup`` from the training split and saved with the checkpoint.
"""

from __future__ import annotations

import torch
from torch import nn

from wtml.runtime.predict import rows_per_run

QUANTILE = 0.999
"""The training data's score quantile that sets the threshold (0.1 % of training inputs
score above 1)."""
RESOLUTION = 1e-5
"""The smallest change of a feature, relative to its magnitude, that the gate resolves: a
float32 feature summed over a record (or over chunks, in another order) is rounded at about
this level, so a feature that the training data hold nearly constant (a drive level) must not
turn that rounding into a score."""


class ZeParts(nn.Module):
    """The plainest input features: ``(Re Ze, Im Ze)`` side by side, ``(batch, 2 n_freq)``."""

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor) -> torch.Tensor:
        return torch.cat([ze_re, ze_im], -1)


class DomainGate(nn.Module):
    """Whitened distance of input features from the training data, and output ranges.

    Args:
        features: ``(*inputs) -> (batch, n_feat)`` float32 (part of the exported graph); the
            inputs are the graph's (``ze_re, ze_im`` and any reference the task takes).
        n_feat: number of features.
        ranges: trained range of each output that is checked, by output index.
        absent: indices of checked outputs for which NaN is a legitimate answer ("nothing to
            locate": a record without a wall) and passes the range check.

    Forward: the inputs, each ``(batch, ...)`` -> ``score (batch,)`` (``<= 1`` inside).
    """

    def __init__(self, features: nn.Module, n_feat: int,
                 ranges: dict[int, tuple[float, float]] | None = None,
                 absent: tuple[int, ...] = ()) -> None:
        super().__init__()
        self.features = features
        # folded for a device (few ONNX ops): ellipsoid |(x - mean) W|² with the scales and
        # the threshold inside W; box max|x a + b| - 10
        self.register_buffer("mean", torch.zeros(n_feat))
        self.register_buffer("whiten", torch.zeros(n_feat, n_feat))
        self.register_buffer("box_a", torch.zeros(n_feat))
        self.register_buffer("box_b", torch.zeros(n_feat))
        self.ranges = dict(ranges or {})
        if set(absent) - set(self.ranges):
            raise ValueError(f"absent {sorted(absent)}: each must be a checked output "
                             f"({sorted(self.ranges)})")
        self.absent = tuple(sorted(absent))
        lo = [self.ranges[k][0] for k in sorted(self.ranges)]
        hi = [self.ranges[k][1] for k in sorted(self.ranges)]
        self.register_buffer("low", torch.tensor(lo, dtype=torch.float32))
        self.register_buffer("high", torch.tensor(hi, dtype=torch.float32))

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        return self.score(self.features(*inputs))

    def score(self, x: torch.Tensor) -> torch.Tensor:
        """The score of features already computed, ``(batch, n_feat)`` -> ``(batch,)``."""
        z = x @ self.whiten + (-self.mean) @ self.whiten  # one Gemm: the constant folds
        # the box: |(x - low)/m - 10| - 10 is 0 on [low, low + 20 m] = the training span's
        # edges, 1 one margin m (5 % of the span) beyond either edge
        box = torch.abs(x * self.box_a + self.box_b).amax(-1) - 10.0
        return torch.maximum((z * z).sum(-1), box)

    def outputs_in_range(self, outputs: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """Whether every checked output lies in its trained range, ``(batch,)`` bool (all
        true when none is checked); NaN passes for the outputs in ``absent``."""
        ok = None
        for j, k in enumerate(sorted(self.ranges)):
            inside = (outputs[k] >= self.low[j]) & (outputs[k] <= self.high[j])
            if k in self.absent:
                inside = inside | torch.isnan(outputs[k])
            ok = inside if ok is None else ok & inside
        return torch.ones_like(outputs[0], dtype=torch.bool) if ok is None else ok

    def inputs_only(self) -> DomainGate:
        """The same input statistics without output ranges (for a graph whose outputs have
        no trained range, such as the classical path)."""
        gate = DomainGate(self.features, len(self.mean))
        for name in ("mean", "whiten", "box_a", "box_b"):
            getattr(gate, name).copy_(getattr(self, name))
        return gate

    @torch.no_grad()
    def fit(self, *inputs: torch.Tensor, quantile: float = QUANTILE, floor: float = 1e-9
            ) -> DomainGate:
        """Fit the whitening (float64) and the box to training ``inputs`` (the graph's, each
        ``(n, ...)``), then set the threshold
        at ``quantile`` of their scores as this float32 gate computes them.

        Whitening: the standardised features' covariance eigenvectors, each scaled by
        ``1/sqrt(max(λ, floor·λ_max))`` (the floor keeps directions that the training data
        never vary in from dividing by zero, and float32 rounding from mattering there); each
        feature's scale and box margin are at least :data:`RESOLUTION` of its magnitude, and
        the covariance holds that much independent noise on each feature."""
        if not 0.5 <= quantile < 1:
            raise ValueError(f"quantile must be in [0.5, 1), got {quantile}")
        # rows of a few MB at a time, of the inputs and of their features in float64 (the
        # larger): the texture gate's 1280 windows of 12800 samples at once took its features'
        # frames to 0.65 GB more than the rest of training; float64 copies of all of
        # radial_spread's 180000 rows of 80 features, its training's start 0.36 GB
        rows = rows_per_run(max(sum(x[:1].numel() * x.element_size() for x in inputs),
                                8 * len(self.mean)))
        chunks = [tuple(x[s:s + rows] for x in inputs) for s in range(0, len(inputs[0]), rows)]
        x = torch.cat([self.features(*chunk) for chunk in chunks])  # as computed: float32
        parts = x.split(rows)
        n = len(x)
        size = x.abs().amax(0).double()
        mean = sum(part.double().sum(0) for part in parts) / n
        std = (sum(((part.double() - mean) ** 2).sum(0) for part in parts) / (n - 1)).sqrt()
        scale = torch.maximum(std, RESOLUTION * size).clamp_min(1e-30)
        # rounding at RESOLUTION is independent noise on each feature: the covariance holds
        # it, so no direction is whitened finer than float32 resolves
        cov = (sum(z.T @ z for z in ((part.double() - mean) / scale for part in parts)) / (n - 1)
               + torch.diag((RESOLUTION * size / scale) ** 2))
        lam, vec = torch.linalg.eigh(cov)
        whiten = (vec / lam.clamp_min(floor * float(lam.max())).sqrt()) / scale[:, None]
        low, high = x.min(0).values.double(), x.max(0).values.double()
        # 5 % of each feature's span, at least what float32 resolves
        margin = torch.maximum((high - low) / 20, RESOLUTION * size).clamp_min(1e-30)
        self.box_a.copy_((1 / margin).float())
        self.box_b.copy_((-low / margin - 10).float())
        self.mean.copy_(mean.float())
        self.whiten.copy_(whiten.float())
        scores = torch.cat([self(*chunk) for chunk in chunks])
        threshold = float(torch.quantile(scores.double(), quantile))
        self.whiten.copy_((whiten / threshold**0.5).float())  # score 1 at the quantile
        return self


class Gated(nn.Module):
    """A net with its domain: ``(*inputs) -> (*outputs, in_domain, domain_score)``.

    ``in_domain`` is ``domain_score <= 1`` and, for the outputs the gate checks, the answer
    inside its trained range; the outputs at ``uncertain`` (indices) become NaN where it is
    false.

    Where the net's ``features`` is the gate's own module and the net answers from features
    (``net.from_features``), the graph computes them once for both.

    Where ``checks`` are given, the net's last ``len(checks)`` outputs are self-checks of its
    answer (the onset net's wall-motion share and
    :func:`~wtml.decoders.onset.touch_spread`): they leave the graph's outputs, and the domain
    score is the largest of the gate's and each check over its limit, so an answer whose check
    passes its limit is out of domain.

    Args:
        net: the exported net, returning a tuple of ``(batch,)`` tensors.
        gate: its fitted :class:`DomainGate`.
        uncertain: indices of the outputs that are predicted uncertainties.
        checks: the limits of the net's last outputs, in their order (score 1 there); empty:
            no self-check.
    """

    def __init__(self, net: nn.Module, gate: DomainGate, uncertain: tuple[int, ...] = (),
                 checks: tuple[float, ...] = ()) -> None:
        super().__init__()
        self.net, self.gate, self.uncertain = net, gate, tuple(uncertain)
        self.shared = (getattr(net, "features", None) is gate.features
                       and hasattr(net, "from_features"))
        if not all(c > 0 for c in checks):
            raise ValueError(f"checks must be limits > 0, got {checks!r}")
        self.checks = len(checks)
        self.register_buffer("check_limits", torch.tensor([float(c) for c in checks]))

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        if self.shared:
            x = self.gate.features(*inputs)
            outputs, score = tuple(self.net.from_features(x)), self.gate.score(x)
        else:
            outputs, score = tuple(self.net(*inputs)), self.gate(*inputs)
        if self.checks:
            outputs, checks = outputs[:-self.checks], outputs[-self.checks:]
            for k, check in enumerate(checks):
                score = torch.maximum(score, check / self.check_limits[k])
        inside = (score <= 1.0) & self.gate.outputs_in_range(outputs)
        nan = torch.tensor(float("nan"))  # a constant, broadcast (no Shape and Expand)
        outputs = tuple(torch.where(inside, y, nan) if k in self.uncertain else y
                        for k, y in enumerate(outputs))
        return (*outputs, inside, score)
