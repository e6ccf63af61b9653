"""The Timed Action Prediction Model (TAPM): one future steering action per latency in delta_TAPM.

Inputs come from the frozen Base Model: its action a_BM, its image features z_o and its speed
features z_v (paper eq. 2, Figure 5b). a_BM -> FC 100, z_o -> FC 500, z_v -> FC 100 (ReLU),
concatenated (700) and fed to N heads, each FC 200 (ReLU), Dropout 0.3, FC 100 (ReLU),
Dropout 0.3, FC 50 (tanh), FC 1 (tanh).

The N heads run as one batched computation: their first layers share the 700-wide input and are
one ``nn.Linear(700, N * 200)``; the later layers are :class:`GroupedLinear` (one ``baddbmm`` for
all heads). Mathematically this is N independent sub-models (same parameter count, independent
weights, independent dropout masks); it avoids a Python loop per head, which at batch size 1
would cost more than the arithmetic.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from plm_highway.models.base_model import SPEED_FEATURES

DEFAULT_DELTA_GRID_S: tuple[float, ...] = (0.15, 0.20, 0.25, 0.30, 0.35)
ACTION_FEATURES, IMAGE_FEATURES, SPEED_TRUNK_FEATURES = 100, 500, 100
HEAD_WIDTHS = (200, 100, 50)


@dataclass(frozen=True)
class TAPMConfig:
    image_feature_dim: int
    speed_feature_dim: int = SPEED_FEATURES
    delta_grid_s: tuple[float, ...] = DEFAULT_DELTA_GRID_S
    dropout: float = 0.3

    def __post_init__(self) -> None:
        # JSON round trips give lists; the grid is part of the config's identity, so keep it a tuple.
        object.__setattr__(self, "delta_grid_s", tuple(float(d) for d in self.delta_grid_s))
        validate_delta_grid(self.delta_grid_s)

    @property
    def n_heads(self) -> int:
        return len(self.delta_grid_s)


def validate_delta_grid(delta_grid_s: tuple[float, ...]) -> None:
    """Latencies must be finite, > 0 (0 is the BM's) and strictly increasing."""
    if not delta_grid_s:
        raise ValueError("delta_grid_s: at least one latency is needed")
    if not all(math.isfinite(d) and d > 0 for d in delta_grid_s):
        raise ValueError(f"delta_grid_s: latencies must be finite and > 0 s, got {list(delta_grid_s)}")
    if any(later <= earlier for earlier, later in itertools.pairwise(delta_grid_s)):
        raise ValueError(f"delta_grid_s: latencies must be strictly increasing, got {list(delta_grid_s)}")


class GroupedLinear(nn.Module):
    """``n_groups`` independent linear layers applied to (n_groups, B, in) in one batched matmul."""

    def __init__(self, n_groups: int, in_features: int, out_features: int):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(n_groups, in_features, out_features))
        self.bias = nn.Parameter(torch.empty(n_groups, 1, out_features))
        # nn.Linear's default initialisation, per group.
        bound = 1.0 / math.sqrt(in_features)
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.baddbmm(self.bias, x, self.weight)


class TAPM(nn.Module):
    def __init__(self, config: TAPMConfig):
        super().__init__()
        self.config = config
        self.action_fc = nn.Linear(1, ACTION_FEATURES)
        self.image_fc = nn.Linear(config.image_feature_dim, IMAGE_FEATURES)
        self.speed_fc = nn.Linear(config.speed_feature_dim, SPEED_TRUNK_FEATURES)
        trunk_width = ACTION_FEATURES + IMAGE_FEATURES + SPEED_TRUNK_FEATURES
        n_heads = config.n_heads
        self.heads_in = nn.Linear(trunk_width, n_heads * HEAD_WIDTHS[0])
        self.heads_hidden = GroupedLinear(n_heads, HEAD_WIDTHS[0], HEAD_WIDTHS[1])
        self.heads_tanh = GroupedLinear(n_heads, HEAD_WIDTHS[1], HEAD_WIDTHS[2])
        self.heads_out = GroupedLinear(n_heads, HEAD_WIDTHS[2], 1)

    def forward(self, a_bm: torch.Tensor, z_o: torch.Tensor, z_v: torch.Tensor) -> torch.Tensor:
        """a_BM (B,), z_o (B, image_feature_dim), z_v (B, 144) -> future steering (B, N)."""
        # ReLU applied once to the concatenation = ReLU on each of the three FC layers.
        trunk = torch.cat([self.action_fc(a_bm.view(-1, 1)), self.image_fc(z_o), self.speed_fc(z_v)], dim=1)
        hidden = F.relu(self.heads_in(F.relu(trunk)))
        # (B, N * 200) -> (N, B, 200): heads first, for baddbmm.
        hidden = hidden.view(len(hidden), self.config.n_heads, HEAD_WIDTHS[0]).transpose(0, 1)
        hidden = F.relu(self.heads_hidden(self._dropout(hidden)))
        hidden = torch.tanh(self.heads_tanh(self._dropout(hidden)))
        return torch.tanh(self.heads_out(hidden)).squeeze(-1).transpose(0, 1)

    def _dropout(self, x: torch.Tensor) -> torch.Tensor:
        # Skipping the call in eval mode saves an op per layer at batch size 1.
        return F.dropout(x, self.config.dropout, training=True) if self.training else x
