"""Export-safe building blocks: complex algebra written out in real arithmetic.

ONNX has no complex tensors, so a T on the grid is held as real and imaginary buffers and
``Zm = (t22 Ze - t12) / (t11 - t21 Ze)`` is evaluated by hand.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


class ZmFromZe(nn.Module):
    """Calibrated T -> load impedance, in float32 real arithmetic.

    Args:
        t: complex T, shape ``(n_freq, 2, 2)`` (numpy).

    Forward: ``ze_re, ze_im`` of shape ``(batch, n_freq)`` in Ω -> ``zm_re, zm_im`` in N·s/m.
    """

    def __init__(self, t: np.ndarray) -> None:
        super().__init__()
        t = np.asarray(t, dtype=complex)
        for name, (i, j) in {"t11": (0, 0), "t12": (0, 1), "t21": (1, 0), "t22": (1, 1)}.items():
            self.register_buffer(f"{name}_re", torch.tensor(t[:, i, j].real, dtype=torch.float32))
            self.register_buffer(f"{name}_im", torch.tensor(t[:, i, j].imag, dtype=torch.float32))

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        num_re = self.t22_re * ze_re - self.t22_im * ze_im - self.t12_re
        num_im = self.t22_re * ze_im + self.t22_im * ze_re - self.t12_im
        den_re = self.t11_re - (self.t21_re * ze_re - self.t21_im * ze_im)
        den_im = self.t11_im - (self.t21_re * ze_im + self.t21_im * ze_re)
        mag2 = den_re * den_re + den_im * den_im
        return ((num_re * den_re + num_im * den_im) / mag2,
                (num_im * den_re - num_re * den_im) / mag2)
