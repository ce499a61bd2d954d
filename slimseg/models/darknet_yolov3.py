"""Darknet-19 backbone + YOLOv3 head (three anchor-based levels at strides 8/16/32).

The layer list follows ``darknet19.cfg`` layers 0–22 (18 convs, classifier dropped) and the
head of ``yolov3.cfg``; ``Darknet19YOLOv3.darknet_convs()`` lists every convolution in cfg
order so ``slimseg.models.darknet_weights`` can read and write darknet ``.weights`` files.

BatchNorm numerics: darknet normalises with ``(x - mean) / (sqrt(var) + 1e-6)``, PyTorch with
``(x - mean) / sqrt(var + eps)``. With ``eps = 1e-12`` the two denominators differ by less
than 1e-6 absolute for *every* ``var >= 0`` (``sqrt(var) <= sqrt(var + 1e-12) <= sqrt(var) +
1e-6``, equal at ``var = 0``), whereas ``eps = 1e-6`` is off by up to ~1e-3 absolute and by
orders of magnitude for near-zero-variance channels. Hence ``DARKNET_BN_EPS = 1e-12``
(pass ``bn_eps`` to override, e.g. 1e-5 for extra stability when training from scratch).
BatchNorm momentum 0.01 mirrors darknet's running update ``0.99 * old + 0.01 * batch``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from slimseg.layers.conv import ConvBNAct
from slimseg.models.base import ZooModel
from slimseg.models.heads.decode import YOLO_STRIDES as STRIDES
from slimseg.models.specs import ModelSpec
from slimseg.ops.nms import yolov3_to_rows
from slimseg.utils.full_precision import full_precision

# (w, h) in input pixels, one tuple per level, ordered stride 8, 16, 32 (yolov3.cfg masks
# 0,1,2 | 3,4,5 | 6,7,8).
STANDARD_ANCHORS: tuple[tuple[tuple[int, int], ...], ...] = (
    ((10, 13), (16, 30), (33, 23)),
    ((30, 61), (62, 45), (59, 119)),
    ((116, 90), (156, 198), (373, 326)),
)

DARKNET_BN_EPS = 1e-12
DARKNET_BN_MOMENTUM = 0.01

# darknet19.cfg layers 0-22 without the pools: (filters, kernel); "M" = 2x2/2 maxpool.
# Taps (backbone outputs) follow conv 10 (256 ch), conv 16 (512 ch), conv 22 (1024 ch).
_DARKNET19_STAGES: tuple[tuple[int | str, ...], ...] = (
    # stride 8: conv 0, M, conv 2, M, conv 4-6, M, conv 8-10
    ((32, 3), "M", (64, 3), "M", (128, 3), (64, 1), (128, 3), "M", (256, 3), (128, 1), (256, 3)),
    # stride 16: M, conv 12-16
    ("M", (512, 3), (256, 1), (512, 3), (256, 1), (512, 3)),
    # stride 32: M, conv 18-22
    ("M", (1024, 3), (512, 1), (1024, 3), (512, 1), (1024, 3)),
)


def _dn_conv(c_in: int, c_out: int, k: int, bn_eps: float, fused: bool) -> ConvBNAct:
    """Darknet ``[convolutional] batch_normalize=1 pad=1 activation=leaky`` (stride 1)."""
    return ConvBNAct(
        c_in,
        c_out,
        k,
        1,
        act="leaky",
        bn_eps=bn_eps,
        bn_momentum=DARKNET_BN_MOMENTUM,
        fused=fused,
    )


class Darknet19(nn.Module):
    """Darknet-19 feature extractor (darknet19.cfg layers 0–22, 18 convs, no classifier).

    ``[B, 3, H, W] → ([B, 256, H/8, W/8], [B, 512, H/16, W/16], [B, 1024, H/32, W/32])``
    for ``H``, ``W`` multiples of 32.
    """

    out_channels: tuple[int, int, int] = (256, 512, 1024)

    def __init__(self, bn_eps: float = DARKNET_BN_EPS, fused: bool = False) -> None:
        super().__init__()
        stages: list[nn.Sequential] = []
        c_in = 3
        for spec in _DARKNET19_STAGES:
            layers: list[nn.Module] = []
            for item in spec:
                if item == "M":
                    layers.append(nn.MaxPool2d(2, 2))
                else:
                    c_out, k = item  # type: ignore[misc]
                    layers.append(_dn_conv(c_in, c_out, k, bn_eps, fused))
                    c_in = c_out
            stages.append(nn.Sequential(*layers))
        self.stage1, self.stage2, self.stage3 = stages

    def convs(self) -> list[ConvBNAct]:
        """The 18 convolutions in darknet19.cfg order."""
        return [m for m in self.modules() if isinstance(m, ConvBNAct)]

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        c3 = self.stage1(x)
        c4 = self.stage2(c3)
        c5 = self.stage3(c4)
        return c3, c4, c5


class YOLOv3Block(nn.Module):
    """One YOLOv3 level: five alternating 1×1/3×3 convs, a 3×3, and a linear 1×1 predictor.

    ``[B, c_in, H, W] → (branch [B, c, H, W], pred [B, n_out, H, W])``; ``branch`` is the
    output of the 5th conv (yolov3.cfg ``[route] layers=-4``), ``pred`` the raw logits.
    """

    def __init__(
        self, c_in: int, c: int, n_out: int, bn_eps: float = DARKNET_BN_EPS, fused: bool = False
    ) -> None:
        super().__init__()
        self.convs = nn.Sequential(
            _dn_conv(c_in, c, 1, bn_eps, fused),
            _dn_conv(c, 2 * c, 3, bn_eps, fused),
            _dn_conv(2 * c, c, 1, bn_eps, fused),
            _dn_conv(c, 2 * c, 3, bn_eps, fused),
            _dn_conv(2 * c, c, 1, bn_eps, fused),
        )
        self.out_conv = _dn_conv(c, 2 * c, 3, bn_eps, fused)
        self.pred = nn.Conv2d(2 * c, n_out, 1, 1, 0, bias=True)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        branch = self.convs(x)
        return branch, self.pred(self.out_conv(branch))


class Darknet19YOLOv3(ZooModel):
    """YOLOv3 detector on a Darknet-19 backbone, darknet-compatible layer for layer.

    Input ``[B, 3, H, W]`` with ``H``, ``W`` multiples of 32 (RGB, 0–1).

    * Training mode: a list of three raw prediction tensors, one per stride 8, 16, 32, each
      ``[B, na, 5 + nc, H/s, W/s]`` (``na = 3``). It is a free view of the predictor output
      ``[B, na·(5+nc), H/s, W/s]`` whose channel ``a·(5+nc) + k`` holds entry ``k`` =
      ``(tx, ty, tw, th, obj, cls_0, …)`` of anchor ``a`` — darknet's own channel layout.
    * Eval mode: one decoded tensor ``[B, 5 + nc, A]``, ``A = na · Σ_i (H/s_i)·(W/s_i)``
      (10,647 at 416×416), rows ``(cx, cy, w, h, obj, cls_0, …)``: box centre and size in
      input pixels, objectness and class probabilities after sigmoid. Columns are ordered
      level (stride 8, 16, 32) → anchor → cell (row-major). Darknet decoding:
      ``xy = (cell + σ(t_xy))·stride``, ``wh = exp(t_wh)·anchor``. No NMS.

    ``spec.anchors``: per level ``((w, h), …)`` in input pixels, levels ordered stride 8, 16,
    32 (``None``: YOLOv3's standard anchors); every level must have the same number of anchors.
    ``fused=True`` builds the BN-fused structure that ``fuse_model(model).state_dict()`` loads
    into.
    """

    @staticmethod
    def detection_rows(pred: torch.Tensor) -> torch.Tensor:
        """``[B, 5 + nc, A]`` (objectness, class probabilities) → ``[B, 4 + nc, A]`` rows
        with class score = objectness · class probability."""
        return yolov3_to_rows(pred)

    def __init__(
        self, spec: ModelSpec, fused: bool = False, bn_eps: float = DARKNET_BN_EPS
    ) -> None:
        super().__init__(spec)
        num_classes = spec.num_classes
        anchors = STANDARD_ANCHORS if spec.anchors is None else spec.anchors
        if num_classes < 1:
            raise ValueError(f"num_classes must be >= 1, got {num_classes}")
        if len(anchors) != len(STRIDES):
            raise ValueError(f"need anchors for {len(STRIDES)} levels, got {len(anchors)}")
        na = len(anchors[0])
        if na < 1 or any(len(level) != na for level in anchors):
            raise ValueError(f"every level needs the same (>0) number of anchors: {anchors}")
        self.num_anchors = na
        self.num_outputs = 5 + num_classes  # per anchor: tx, ty, tw, th, obj, classes
        self.strides: tuple[int, int, int] = STRIDES
        # [levels, na, 2] (w, h) in pixels; a buffer so it follows .to()/.double() and is
        # traced as a constant.
        self.register_buffer(
            "anchors", torch.tensor(anchors, dtype=torch.float32).reshape(len(STRIDES), na, 2)
        )

        n_out = na * self.num_outputs
        c3, c4, c5 = Darknet19.out_channels
        self.backbone = Darknet19(bn_eps, fused)
        self.head_p5 = YOLOv3Block(c5, 512, n_out, bn_eps, fused)
        self.lateral_p5 = _dn_conv(512, 256, 1, bn_eps, fused)
        self.head_p4 = YOLOv3Block(256 + c4, 256, n_out, bn_eps, fused)
        self.lateral_p4 = _dn_conv(256, 128, 1, bn_eps, fused)
        self.head_p3 = YOLOv3Block(128 + c3, 128, n_out, bn_eps, fused)
        self._init_pred_biases()

    @torch.no_grad()
    def _init_pred_biases(self, image_size: int = 416) -> None:
        """Prior biases for training from scratch (darknet weights overwrite them).

        Objectness starts near 8 objects per image spread over the level's cells; class
        logits near probability 0.6 / nc. Box logits stay 0 (σ = 0.5, exp = 1).
        """
        for head, stride in zip(
            (self.head_p3, self.head_p4, self.head_p5), self.strides, strict=True
        ):
            bias = head.pred.bias.view(self.num_anchors, self.num_outputs)
            bias[:, :4] = 0.0
            bias[:, 4] = math.log(8.0 / (image_size / stride) ** 2)
            bias[:, 5:] = math.log(0.6 / max(self.num_classes - 0.99, 0.01))

    def darknet_convs(self) -> list[ConvBNAct | nn.Conv2d]:
        """All 41 convolutions in darknet cfg order (the order of a ``.weights`` file).

        Backbone (18, darknet19.cfg), then yolov3.cfg: P5 set (6) + pred, the 1×1 256
        lateral, P4 set (6) + pred, the 1×1 128 lateral, P3 set (6) + pred.
        """
        convs: list[ConvBNAct | nn.Conv2d] = list(self.backbone.convs())
        for head, lateral in (
            (self.head_p5, self.lateral_p5),
            (self.head_p4, self.lateral_p4),
            (self.head_p3, None),
        ):
            convs.extend(head.convs)
            convs.append(head.out_conv)
            convs.append(head.pred)
            if lateral is not None:
                convs.append(lateral)
        return convs

    def forward(self, x: torch.Tensor) -> list[torch.Tensor] | torch.Tensor:
        """``[B, 3, H, W]`` → training: 3 × ``[B, na, 5+nc, H/s, W/s]``; eval: ``[B, 5+nc, A]``."""
        c3, c4, c5 = self.backbone(x)
        branch5, p5 = self.head_p5(c5)
        up5 = F.interpolate(self.lateral_p5(branch5), scale_factor=2.0, mode="nearest")
        branch4, p4 = self.head_p4(torch.cat((up5, c4), 1))
        up4 = F.interpolate(self.lateral_p4(branch4), scale_factor=2.0, mode="nearest")
        _, p3 = self.head_p3(torch.cat((up4, c3), 1))

        preds = [
            p.view(p.shape[0], self.num_anchors, self.num_outputs, p.shape[2], p.shape[3])
            for p in (p3, p4, p5)
        ]
        if self.training:
            return preds
        with full_precision(x.device):  # float32 boxes and scores under autocast too
            return torch.cat([self._decode(p.float(), i) for i, p in enumerate(preds)], 2)

    def _decode(self, p: torch.Tensor, level: int) -> torch.Tensor:
        """Raw ``[B, na, 5+nc, h, w]`` → decoded ``[B, 5+nc, na·h·w]`` (anchor-major)."""
        b, na, no, h, w = p.shape
        stride = self.strides[level]
        ys = torch.arange(h, device=p.device, dtype=p.dtype)
        xs = torch.arange(w, device=p.device, dtype=p.dtype)
        gy, gx = torch.meshgrid(ys, xs, indexing="ij")
        grid = torch.stack((gx, gy), 0).view(1, 1, 2, h, w)  # (col, row) per cell
        anchor_wh = self.anchors[level].to(p.dtype).view(1, na, 2, 1, 1)

        sig = p.sigmoid()
        xy = (sig[:, :, 0:2] + grid) * stride
        wh = torch.exp(p[:, :, 2:4]) * anchor_wh
        out = torch.cat((xy, wh, sig[:, :, 4:]), 2)  # [B, na, no, h, w]
        return out.permute(0, 2, 1, 3, 4).reshape(b, no, na * h * w)
