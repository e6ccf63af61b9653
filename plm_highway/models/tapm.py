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

:meth:`TAPM.heads` can run a contiguous range of heads only: PLM-Net inference needs just the two
that bracket the measured latency (Algorithm 1), and a head's output does not depend on the others.

Architecture bounds (checked before allocation; a checkpoint's ``architecture`` is a
:class:`TAPMConfig`): ``image_feature_dim`` in [1, :data:`MAX_IMAGE_FEATURE_DIM`] (the most a BM within
its bounds produces), ``speed_feature_dim`` in [1, 4096], ``delta_grid_s`` a list of 1 to
:data:`MAX_HEADS` latencies, finite, in (0, :data:`MAX_GRID_LATENCY_S`] s and strictly increasing,
``dropout`` in [0, 1).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from plm_highway.models.base_model import MAX_IMAGE_SIDE_PX, SPEED_FEATURES, BaseModelConfig
from plm_highway.models.config_checks import check_int, check_number

MAX_IMAGE_FEATURE_DIM = BaseModelConfig(
    image_height_px=MAX_IMAGE_SIDE_PX, image_width_px=MAX_IMAGE_SIDE_PX
).image_feature_dim
MAX_SPEED_FEATURE_DIM = 4096
MAX_HEADS = 32
MAX_GRID_LATENCY_S = 10.0
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
        check_int("image_feature_dim", self.image_feature_dim, 1, MAX_IMAGE_FEATURE_DIM)
        check_int("speed_feature_dim", self.speed_feature_dim, 1, MAX_SPEED_FEATURE_DIM)
        check_number("dropout", self.dropout, 0.0, 1.0, high_open=True)
        if isinstance(self.delta_grid_s, str) or not isinstance(self.delta_grid_s, list | tuple):
            raise ValueError(
                f"delta_grid_s: expected a list of latencies in seconds, got "
                f"{type(self.delta_grid_s).__name__} {self.delta_grid_s!r}"
            )
        # JSON round trips give lists; the grid is part of the config's identity, so keep it a tuple.
        object.__setattr__(self, "delta_grid_s", validate_delta_grid(self.delta_grid_s))

    @property
    def n_heads(self) -> int:
        return len(self.delta_grid_s)


def validate_delta_grid(delta_grid_s, field: str = "delta_grid_s") -> tuple[float, ...]:
    """The grid as a tuple of floats: 1 to MAX_HEADS latencies, finite, > 0 (0 is the BM's), increasing."""
    if not 1 <= len(delta_grid_s) <= MAX_HEADS:
        raise ValueError(f"{field}: expected 1 to {MAX_HEADS} latencies, got {len(delta_grid_s)}")
    for latency_s in delta_grid_s:
        if isinstance(latency_s, bool) or not isinstance(latency_s, int | float) or not (
            math.isfinite(latency_s) and 0 < latency_s <= MAX_GRID_LATENCY_S
        ):
            raise ValueError(
                f"{field}: latencies must be finite numbers in (0, {MAX_GRID_LATENCY_S:g}] s, "
                f"got {latency_s!r} in {list(delta_grid_s)}"
            )
    if any(later <= earlier for earlier, later in itertools.pairwise(delta_grid_s)):
        raise ValueError(f"{field}: latencies must be strictly increasing, got {list(delta_grid_s)}")
    return tuple(float(latency_s) for latency_s in delta_grid_s)


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

    def forward(self, x: torch.Tensor, first: int = 0, stop: int | None = None) -> torch.Tensor:
        """Groups ``first .. stop - 1`` (all by default) on x (stop - first, B, in)."""
        if first == 0 and stop is None:
            return torch.baddbmm(self.bias, x, self.weight)
        return torch.baddbmm(self.bias[first:stop], x, self.weight[first:stop])


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
        return self.heads(self.trunk(a_bm, self.image_fc(z_o), z_v))

    def trunk(self, a_bm: torch.Tensor, image_features: torch.Tensor, z_v: torch.Tensor) -> torch.Tensor:
        """The shared 700-wide input of the heads; ``image_features`` is ``image_fc(z_o)`` (B, 500)."""
        # ReLU applied once to the concatenation = ReLU on each of the three FC layers.
        return F.relu(torch.cat([self.action_fc(a_bm.view(-1, 1)), image_features, self.speed_fc(z_v)], dim=1))

    def heads(self, trunk: torch.Tensor, first: int = 0, stop: int | None = None) -> torch.Tensor:
        """Heads ``first .. stop - 1`` (all by default) on the trunk (B, 700) -> (B, stop - first)."""
        stop = self.config.n_heads if stop is None else stop
        if not 0 <= first < stop <= self.config.n_heads:
            raise ValueError(f"heads: range [{first}, {stop}) is not within the {self.config.n_heads} heads")
        n_heads, width = stop - first, HEAD_WIDTHS[0]
        # Contiguous heads are contiguous slices of every weight: views, no copies.
        rows = slice(first * width, stop * width)
        hidden = F.relu(F.linear(trunk, self.heads_in.weight[rows], self.heads_in.bias[rows]))
        # (B, n * 200) -> (n, B, 200): heads first, for baddbmm.
        hidden = hidden.view(len(hidden), n_heads, width).transpose(0, 1)
        hidden = F.relu(self.heads_hidden(self._dropout(hidden), first, stop))
        hidden = torch.tanh(self.heads_tanh(self._dropout(hidden), first, stop))
        return torch.tanh(self.heads_out(hidden, first, stop)).squeeze(-1).transpose(0, 1)

    def _dropout(self, x: torch.Tensor) -> torch.Tensor:
        # Skipping the call in eval mode saves an op per layer at batch size 1.
        return F.dropout(x, self.config.dropout, training=True) if self.training else x
