"""YOLOv8-seg mask branch: per-level mask coefficients and the prototype generator."""

from __future__ import annotations

import torch
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.models.heads.branch import conv_branch


class Proto(nn.Module):
    """3×3 conv, 2×2 stride-2 transposed conv, 3×3 conv, 1×1 conv to ``num_masks``.

    ``[B, c_in, H, W]`` (P3, stride 8) → ``[B, num_masks, 2H, 2W]`` (a quarter of the input
    size): the reference prototype module, with ``stride=4`` and no ``skip_channels``.

    The finer path (``docs/architecture.md`` §7): ``skip_channels[4]`` adds a 1×1 lateral of
    the backbone's stride-4 feature to the upsampled map before the second 3×3 conv;
    ``stride=2`` then rearranges that conv's ``hidden`` channels at stride 4 into
    ``hidden/4`` channels at stride 2 (pixel shuffle: ONNX DepthToSpace, CRD), adds a 1×1
    lateral of the stem conv's stride-2 output there (``skip_channels[2]``), and the last 1×1
    conv emits ``[B, num_masks, 4H, 4W]``. The shuffle keeps the last conv's cost equal to
    the reference's (4× the pixels, a quarter of the channels), so the finer path costs
    only its laterals. ``forward`` then takes ``skips`` =
    ``{stride: [B, c, H_in/stride, W_in/stride]}``.
    """

    def __init__(
        self,
        c_in: int,
        hidden: int,
        num_masks: int = 32,
        fused: bool = False,
        stride: int = 4,
        skip_channels: dict[int, int] | None = None,
    ) -> None:
        super().__init__()
        skip_channels = skip_channels or {}
        if stride not in (2, 4) or any(s not in (2, 4) or s < stride for s in skip_channels):
            raise ValueError(f"stride {stride} with skips {sorted(skip_channels)} is not valid")
        if stride == 2 and hidden % 4:
            raise ValueError(f"stride 2 needs hidden channels divisible by 4, got {hidden}")
        self.skip_strides = tuple(sorted(skip_channels, reverse=True))
        fine = hidden // 4 if stride == 2 else hidden
        self.cv1 = ConvBNAct(c_in, hidden, 3, fused=fused)
        self.upsample = nn.ConvTranspose2d(hidden, hidden, 2, 2, 0, bias=True)
        self.cv2 = ConvBNAct(hidden, hidden, 3, fused=fused)
        self.shuffle = nn.PixelShuffle(2) if stride == 2 else nn.Identity()
        self.cv3 = ConvBNAct(fine, num_masks, 1, fused=fused)
        self.laterals = nn.ModuleDict(
            {
                str(s): ConvBNAct(c, hidden if s == 4 else fine, 1, fused=fused)
                for s, c in sorted(skip_channels.items(), reverse=True)
            }
        )

    def forward(
        self, x: torch.Tensor, skips: dict[int, torch.Tensor] | None = None
    ) -> torch.Tensor:
        if self.skip_strides and (skips is None or not set(self.skip_strides) <= set(skips)):
            raise ValueError(f"this prototype path needs the backbone features {self.skip_strides}")
        y = self.upsample(self.cv1(x))
        if "4" in self.laterals:
            y = y + self.laterals["4"](skips[4])
        y = self.shuffle(self.cv2(y))
        if "2" in self.laterals:
            y = y + self.laterals["2"](skips[2])
        return self.cv3(y)


class MaskCoefficients(nn.Module):
    """Per level 3×3, 3×3, 1×1 → ``num_masks`` raw coefficients, width ``max(c_P3/4, nm)``.

    Per-level inputs ``[B, c_i, H_i, W_i]`` → ``[B, num_masks, A]`` with ``A = Σ H_i·W_i``.
    """

    def __init__(self, in_channels: tuple[int, ...], num_masks: int, fused: bool = False) -> None:
        super().__init__()
        width = max(in_channels[0] // 4, num_masks)
        self.branches = nn.ModuleList(conv_branch(c, width, num_masks, fused) for c in in_channels)
        self.num_masks = num_masks

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        b = feats[0].shape[0]
        return torch.cat(
            [
                m(x).reshape(b, self.num_masks, -1)
                for x, m in zip(feats, self.branches, strict=True)
            ],
            dim=2,
        )
