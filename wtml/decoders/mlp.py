"""A plain multilayer perceptron (sizes from config)."""

from __future__ import annotations

import torch
from torch import nn


class MLP(nn.Module):
    """``n_in -> hidden... -> n_out`` with an activation (SiLU by default).

    Forward: ``(batch, n_in)`` -> ``(batch, n_out)``.
    """

    def __init__(self, n_in: int, hidden: list[int], n_out: int,
                 activation: type[nn.Module] = nn.SiLU) -> None:
        super().__init__()
        if n_in < 1 or n_out < 1 or any(h < 1 for h in hidden):
            raise ValueError(f"MLP sizes must be >= 1, got {n_in}, {hidden}, {n_out}")
        self.n_in = n_in
        layers: list[nn.Module] = []
        width = n_in
        for h in hidden:
            layers += [nn.Linear(width, h), activation()]
            width = h
        layers.append(nn.Linear(width, n_out))
        self.layers = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)
