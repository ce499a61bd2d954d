"""YOLOv8 detector / instance segmenter composed from backbone, neck and head."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from slimseg.models.backbones.csp_darknet import CSPDarknet
from slimseg.models.base import ZooModel
from slimseg.models.heads.decode import (
    YOLO_STRIDES,
    DistributionFocalDecode,
    anchor_points,
    distances_to_xywh,
)
from slimseg.models.heads.decoupled import DecoupledDetect
from slimseg.models.heads.masks import MaskCoefficients, Proto
from slimseg.models.heads.shared_rep import SharedRepDetect
from slimseg.models.necks.pan import PAN
from slimseg.models.specs import ModelSpec
from slimseg.utils.full_precision import full_precision


class RawOutputs(NamedTuple):
    """Training-mode outputs, what the loss consumes.

    ``feats``: per level ``[B, 4·reg_max + nc, H_i, W_i]`` (box logits, then class logits);
    ``mask_coeffs``: ``[B, nm, A]`` raw coefficients (None for detect); ``proto``:
    ``[B, nm, H/s, W/s]`` with ``s = spec.head.proto_stride`` (4, or 2 for the finer path;
    None for detect).
    """

    feats: list[torch.Tensor]
    mask_coeffs: torch.Tensor | None
    proto: torch.Tensor | None


class YOLO(ZooModel):
    """YOLOv8 family network built from a ``ModelSpec``.

    Eval forward on ``[B, 3, H, W]`` (H, W multiples of 32) returns the deployment layout, in
    float32 whatever the ambient autocast:
    segment → ``(pred [B, 4 + nc + nm, A], proto [B, nm, H/s, W/s])`` (``s`` =
    ``spec.head.proto_stride``, 4 unless the finer prototype path is on); detect →
    ``pred [B, 4 + nc, A]``. ``pred`` rows: cx, cy, w, h in input pixels, nc sigmoid class
    scores, nm raw mask coefficients; ``A = Σ (H/s)(W/s)`` over strides 8, 16, 32.
    Training forward returns ``RawOutputs``.
    """

    def __init__(self, spec: ModelSpec, fused: bool = False) -> None:
        super().__init__(spec)
        if spec.scale is None:
            raise ValueError(f"{spec.name}: a yolov8 spec needs a 'scale' section")
        self.strides = YOLO_STRIDES
        self.reg_max = spec.head.reg_max
        scaler = spec.scale
        self.backbone = CSPDarknet(scaler, fused=fused)
        self.neck = PAN(self.backbone.out_channels, scaler, kind=spec.neck, fused=fused)
        chans = self.neck.out_channels
        head = spec.head
        if head.kind == "decoupled":
            self.detect: nn.Module = DecoupledDetect(chans, spec.num_classes, head.reg_max, fused)
        elif head.kind == "shared-rep":
            self.detect = SharedRepDetect(
                chans,
                spec.num_classes,
                scaler.channels(head.hidden),
                share_repconv=head.share_repconv,
                reg_max=head.reg_max,
                fused=fused,
            )
        else:
            raise ValueError(f"{spec.name}: head kind {head.kind!r} is not a YOLOv8 head")
        self.segment = spec.task == "segment"
        if self.segment:
            self.mask_coeffs = MaskCoefficients(chans, head.num_masks, fused=fused)
            self.proto = Proto(
                chans[0],
                scaler.channels(head.proto_channels),
                head.num_masks,
                fused,
                stride=head.proto_stride,
                skip_channels={s: self.backbone.skip_channels[s] for s in head.proto_skips},
            )
        self.dfl = DistributionFocalDecode(head.reg_max)
        self.detect.init_biases(self.strides)

    def forward_raw(self, images: torch.Tensor) -> RawOutputs:
        """``images [B, 3, H, W]`` → ``RawOutputs`` (used by training and by ``forward``)."""
        if self.segment and self.proto.skip_strides:
            skips, pyramid = self.backbone.features(images)
        else:
            skips, pyramid = None, self.backbone(images)
        feats = list(self.neck(pyramid))
        if self.segment:
            proto = self.proto(feats[0], skips)
            return RawOutputs(self.detect(feats), self.mask_coeffs(feats), proto)
        return RawOutputs(self.detect(feats), None, None)

    def decode(self, raw: RawOutputs) -> torch.Tensor:
        """Per-level logits → ``[B, 4 + nc (+ nm), A]`` float32 deployment rows (see class
        doc), under autocast too: anchors, the DFL expectation and the boxes in float16 would
        be off by up to a few pixels at 640 px."""
        b = raw.feats[0].shape[0]
        sizes = [(f.shape[2], f.shape[3]) for f in raw.feats]
        with full_precision(raw.feats[0].device):
            flat = torch.cat([f.reshape(b, f.shape[1], -1).float() for f in raw.feats], dim=2)
            box_logits, cls_logits = flat.split((4 * self.reg_max, self.num_classes), dim=1)
            points, stride = anchor_points(sizes, self.strides, flat)
            xywh = distances_to_xywh(self.dfl(box_logits), points) * stride.transpose(0, 1)
            rows = [xywh, cls_logits.sigmoid()]
            if raw.mask_coeffs is not None:
                rows.append(raw.mask_coeffs.float())
            return torch.cat(rows, dim=1)

    def forward(
        self, images: torch.Tensor
    ) -> RawOutputs | torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        raw = self.forward_raw(images)
        if self.training:
            return raw
        pred = self.decode(raw)
        return (pred, raw.proto.float()) if self.segment else pred

    def dead_conv_params(self) -> int:
        """Parameters the original code defines but never uses (the slim-neck's ``res`` conv)."""
        return self.neck.dead_conv_params()
