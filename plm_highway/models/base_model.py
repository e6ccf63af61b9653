"""The Base Model (BM): a PilotNet-style lane keeper, image + speed -> normalised steering.

Layers (paper Section 3.2, Figure 5a): five valid-padded convolutions (24, 36, 48 filters 5x5
stride 2; 64, 64 filters 3x3 stride 1), flattened into the image feature vector z_o; speed ->
FC 144 (linear, as in the original) = z_v; concat -> FC 512, 100, 50, 10 (ReLU) with dropout 0.3
after 512/100/50 -> FC 1 -> tanh. Steering is normalised to [-1, 1], positive = left.

Choices that differ from, or are not fixed by, the paper:

- ``conv_activation="relu"`` (default). The original convolutions had no activation, so the five
  of them compose into a single linear filter bank and z_o is a linear function of the pixels;
  PilotNet itself uses ReLU. ``"none"`` reproduces the original. Parameter counts are the same.
- Speed enters divided by ``speed_scale_mps`` so that the embedding sees an O(1) input.
- ``embed_acceleration`` adds the original's acceleration Dense(144) (concatenated before FC 512,
  not part of z_v, which the TAPM reads). The simulator drives at constant speed, so the
  acceleration input defaults to zero everywhere (training and inference): the option exists for
  parity with the original's parameter count.
- The ``paper`` preset reproduces the original's parameter count exactly (5,800,550 speed only;
  5,874,566 with acceleration). Two of its layer shapes exist only for that parity: the original
  read a 3-channel BGR image (our grayscale frame is repeated over ``input_channels``, which makes
  conv1's extra 1,200 weights redundant), and it had a second Dense(10 -> 1) throttle/brake output
  (``throttle_head``, 11 parameters), which this project never evaluates or trains (speed is
  constant). A grayscale steering-only 160x160 BM has 5,799,339 parameters.

Image preprocessing lives in :func:`normalise_frames` and runs inside the model, so callers
always pass raw uint8 frames.

Architecture bounds (checked, with the field named, before any layer is allocated; a checkpoint's
``architecture`` is a :class:`BaseModelConfig`): each image side in [:data:`MIN_IMAGE_SIDE_PX`,
:data:`MAX_IMAGE_SIDE_PX`] px (the upper bound keeps the BM under ~61 M parameters, 243 MB; at
3000x3000 px it would need 4.4 G parameters, 17.7 GB), ``input_channels`` in [1, 4],
``speed_scale_mps`` in (0, 1000], ``dropout`` in [0, 1), booleans as JSON ``true``/``false``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import torch
from torch import nn

from plm_highway.errors import BadInput
from plm_highway.models import batch_invariant
from plm_highway.models.config_checks import check_bool, check_choice, check_int, check_number

# (filters, kernel, stride) of the five convolutions, PilotNet's.
CONV_LAYERS: tuple[tuple[int, int, int], ...] = ((24, 5, 2), (36, 5, 2), (48, 5, 2), (64, 3, 1), (64, 3, 1))
SPEED_FEATURES = 144
MLP_WIDTHS = (512, 100, 50, 10)
CONV_ACTIVATIONS = ("relu", "none")
# The smallest side the valid-padded stack leaves 1 px of (5x5/2 three times, then 3x3 twice).
MIN_IMAGE_SIDE_PX = 61
MAX_IMAGE_SIDE_PX = 400
MAX_INPUT_CHANNELS = 4
MAX_SPEED_SCALE_MPS = 1000.0


def conv_output_size_px(height_px: int, width_px: int) -> tuple[int, int]:
    """Spatial size after the valid-padded convolution stack."""
    height, width = height_px, width_px
    for _, kernel, stride in CONV_LAYERS:
        height, width = (height - kernel) // stride + 1, (width - kernel) // stride + 1
    if height < 1 or width < 1:
        raise BadInput(f"image {height_px}x{width_px} px is too small for the convolution stack")
    return height, width


@dataclass(frozen=True)
class BaseModelConfig:
    image_height_px: int = 66
    image_width_px: int = 200
    input_channels: int = 1
    conv_activation: str = "relu"
    embed_acceleration: bool = False
    throttle_head: bool = False
    speed_scale_mps: float = 20.0
    dropout: float = 0.3

    def __post_init__(self) -> None:
        # Sizes first: everything else allocates in proportion to them.
        check_int("image_height_px", self.image_height_px, MIN_IMAGE_SIDE_PX, MAX_IMAGE_SIDE_PX)
        check_int("image_width_px", self.image_width_px, MIN_IMAGE_SIDE_PX, MAX_IMAGE_SIDE_PX)
        check_int("input_channels", self.input_channels, 1, MAX_INPUT_CHANNELS)
        check_choice("conv_activation", self.conv_activation, CONV_ACTIVATIONS)
        check_bool("embed_acceleration", self.embed_acceleration)
        check_bool("throttle_head", self.throttle_head)
        check_number("speed_scale_mps", self.speed_scale_mps, 0.0, MAX_SPEED_SCALE_MPS, low_open=True)
        check_number("dropout", self.dropout, 0.0, 1.0, high_open=True)

    @property
    def image_size_px(self) -> tuple[int, int]:
        return (self.image_height_px, self.image_width_px)

    @property
    def image_feature_dim(self) -> int:
        height, width = conv_output_size_px(self.image_height_px, self.image_width_px)
        return CONV_LAYERS[-1][0] * height * width


PRESETS: dict[str, BaseModelConfig] = {
    # PilotNet's input size, the simulator's default camera.
    "default": BaseModelConfig(),
    # The original PLM-Net's 160x160 input, with its layer set (see module docstring).
    "paper": BaseModelConfig(image_height_px=160, image_width_px=160, input_channels=3, throttle_head=True),
}


def preset_config(preset: str, **overrides) -> BaseModelConfig:
    if preset not in PRESETS:
        raise BadInput(f"preset: {preset!r} is not one of {sorted(PRESETS)}")
    return replace(PRESETS[preset], **overrides)


def normalise_frames(frames: torch.Tensor) -> torch.Tensor:
    """uint8 (B, H, W) -> float32 (B, 1, H, W) in [-1, 1].

    Per-image min-max stretch to the full range, then x / 127.5 - 1, as the original did: it makes
    the model insensitive to global brightness and contrast. A constant image maps to -1.
    """
    low, high = frames.flatten(1).aminmax(dim=1)  # on the uint8 frames: the same values, a quarter of the bytes
    pixels = frames.to(torch.float32).unsqueeze(1)
    low = low.to(torch.float32).view(-1, 1, 1, 1)
    high = high.to(torch.float32)
    scale = 2.0 / (high.view(-1, 1, 1, 1) - low).clamp_min(1.0)
    return (pixels - low) * scale - 1.0


class BaseModel(nn.Module):
    def __init__(self, config: BaseModelConfig = BaseModelConfig()):
        super().__init__()
        self.config = config
        self.convs = _conv_stack(config)
        self.speed_embedding = nn.Linear(1, SPEED_FEATURES)
        self.accel_embedding = nn.Linear(1, SPEED_FEATURES) if config.embed_acceleration else None
        n_embeddings = 2 if config.embed_acceleration else 1
        self.mlp = _mlp(config.image_feature_dim + n_embeddings * SPEED_FEATURES, config.dropout)
        self.steering_head = nn.Linear(MLP_WIDTHS[-1], 1)
        # Parity-only (see module docstring): never called.
        self.throttle_head = nn.Linear(MLP_WIDTHS[-1], 1) if config.throttle_head else None

    @property
    def image_feature_dim(self) -> int:
        return self.config.image_feature_dim

    def encode(self, frames: torch.Tensor, speed_mps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Frames uint8 (B, H, W) and speed (B,) -> (z_o (B, image_feature_dim), z_v (B, 144))."""
        self._check_frames(frames)
        pixels = normalise_frames(frames)
        if self.config.input_channels > 1:
            pixels = pixels.expand(-1, self.config.input_channels, -1, -1)
        # Without gradients (inference, evaluation) the convolutions run as one oneDNN stack: faster at every
        # batch size and batch-invariant (plm_highway.models.batch_invariant.conv_stack); training needs autograd.
        inference = batch_invariant.is_active() or not torch.is_grad_enabled()
        z_o = batch_invariant.conv_stack(self.convs, pixels) if inference else self.convs(pixels)
        z_v = self.speed_embedding((speed_mps / self.config.speed_scale_mps).view(-1, 1))
        return z_o, z_v

    def steering_from_features(
        self, z_o: torch.Tensor, z_v: torch.Tensor, accel_mps2: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(z_o, z_v) -> steering (B,) in [-1, 1]; the part of the BM after :meth:`encode`."""
        return self.steering_from_first_layer(self.mlp[0](self.mlp_input(z_o, z_v, accel_mps2)))

    def mlp_input(
        self, z_o: torch.Tensor, z_v: torch.Tensor, accel_mps2: torch.Tensor | None = None
    ) -> torch.Tensor:
        """The concatenated features the MLP's first layer reads: (B, image_feature_dim + 144 [+ 144])."""
        features = [z_o, z_v]
        if self.accel_embedding is not None:
            if accel_mps2 is None:
                accel_mps2 = torch.zeros(len(z_o), dtype=z_o.dtype, device=z_o.device)
            features.append(self.accel_embedding(accel_mps2.view(-1, 1)))
        return torch.cat(features, dim=1)

    def steering_from_first_layer(self, first_layer_output: torch.Tensor) -> torch.Tensor:
        """The BM after its first FC layer (its pre-activation, (B, 512)) -> steering (B,).

        Split out so that PLM-Net inference can compute this layer fused with the TAPM's image branch.
        """
        hidden = first_layer_output
        for layer in itertools.islice(self.mlp, 1, None):
            hidden = layer(hidden)
        return torch.tanh(self.steering_head(hidden)).view(-1)

    def forward(
        self, frames: torch.Tensor, speed_mps: torch.Tensor, accel_mps2: torch.Tensor | None = None
    ) -> torch.Tensor:
        z_o, z_v = self.encode(frames, speed_mps)
        return self.steering_from_features(z_o, z_v, accel_mps2)

    def _check_frames(self, frames: torch.Tensor) -> None:
        if frames.dim() != 3 or tuple(frames.shape[1:]) != self.config.image_size_px:
            height, width = self.config.image_size_px
            raise BadInput(f"frames: expected (B, {height}, {width}), got {tuple(frames.shape)}")


def _conv_stack(config: BaseModelConfig) -> nn.Sequential:
    layers: list[nn.Module] = []
    in_channels = config.input_channels
    for filters, kernel, stride in CONV_LAYERS:
        layers.append(nn.Conv2d(in_channels, filters, kernel, stride))
        if config.conv_activation == "relu":
            layers.append(nn.ReLU(inplace=True))  # a convolution's output is needed by nothing else
        in_channels = filters
    layers.append(nn.Flatten())
    return nn.Sequential(*layers)


def _mlp(in_features: int, dropout: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    for index, width in enumerate(MLP_WIDTHS):
        layers += [nn.Linear(in_features, width), nn.ReLU()]
        if index < len(MLP_WIDTHS) - 1:  # no dropout after the last (10-wide) layer
            layers.append(nn.Dropout(dropout))
        in_features = width
    return nn.Sequential(*layers)


def count_parameters(module: nn.Module, trainable: bool | None = None) -> int:
    """All parameters, or only the trainable (``True``) / frozen (``False``) ones."""
    return sum(p.numel() for p in module.parameters() if trainable is None or p.requires_grad == trainable)
