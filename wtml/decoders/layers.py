"""Export-safe building blocks: complex algebra written out in real arithmetic.

ONNX has no complex tensors, so a T on the grid is held as real and imaginary buffers and
Eq. 3.15 is evaluated by hand.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


class ZmFromZe(nn.Module):
    """Calibrated T -> load impedance, in float32 real arithmetic.

    Eq. 3.15 as a Möbius map in its cheapest form: with ``c = t11/t21`` (the clamped Ze),
    ``A = -t22/t21`` and ``B = -det T / t21²``, ``Zm = A + B / (Ze - c)``. The three constants
    are computed once in float64; per sample it is one complex division and one complex
    multiply-add (about half the operations of the quotient form, which matters on devices).

    Args:
        t: complex T, shape ``(n_freq, 2, 2)`` (numpy).

    Forward: ``ze_re, ze_im`` of shape ``(batch, n_freq)`` in Ω -> ``zm_re, zm_im`` in N·s/m.
    """

    def __init__(self, t: np.ndarray) -> None:
        super().__init__()
        t = np.asarray(t, dtype=complex)
        t11, t12, t21, t22 = t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1]
        consts = {"c": t11 / t21, "a": -t22 / t21, "b": -(t11 * t22 - t12 * t21) / t21**2}
        for name, value in consts.items():
            self.register_buffer(f"{name}_re", torch.tensor(value.real, dtype=torch.float32))
            self.register_buffer(f"{name}_im", torch.tensor(value.imag, dtype=torch.float32))

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        d_re, d_im = ze_re - self.c_re, ze_im - self.c_im
        mag2 = d_re * d_re + d_im * d_im
        inv_re, inv_im = d_re / mag2, -d_im / mag2  # 1 / (Ze - c)
        return (self.a_re + self.b_re * inv_re - self.b_im * inv_im,
                self.a_im + self.b_re * inv_im + self.b_im * inv_re)


class StandardPolynomial(nn.Module):
    """``p((x - mean) / scale)`` in Horner form, coefficients lowest degree first: the
    scikit-learn pipeline (StandardScaler, PolynomialFeatures, LinearRegression) of
    ``wtml.baselines.radial.PolynomialRadial`` as an exportable layer.

    Args:
        degree: polynomial degree (the buffers are set by :meth:`load_pipeline`).

    Forward: ``x (batch,)`` -> ``(batch,)``.
    """

    def __init__(self, degree: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.tensor(0.0))
        self.register_buffer("scale", torch.tensor(1.0))
        self.register_buffer("coef", torch.zeros(degree + 1))

    @torch.no_grad()
    def load_pipeline(self, pipeline) -> StandardPolynomial:
        scaler, _, linear = (step for _, step in pipeline.steps)
        coef = np.array(linear.coef_, dtype=float)
        coef[0] += linear.intercept_
        self.mean.fill_(float(scaler.mean_[0]))
        self.scale.fill_(float(scaler.scale_[0]))
        self.coef.copy_(torch.tensor(coef, dtype=torch.float32))
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        u = (x - self.mean) / self.scale
        y = torch.zeros_like(u) + self.coef[-1]
        for c in range(self.coef.shape[0] - 2, -1, -1):
            y = y * u + self.coef[c]
        return y
