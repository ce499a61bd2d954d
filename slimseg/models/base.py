"""The contract every zoo family implements, written down once.

Export, complexity counting, checkpoints, the predictor and training depend on this class,
never on attribute probing. A family subclasses ``ZooModel``, receives its ``ModelSpec`` at
construction and sets ``strides``:

* ``spec`` (``ModelSpec``): the variant as data (stored in every checkpoint and ONNX file);
* ``num_classes``: ``spec.num_classes``;
* ``strides``: the output strides in pixels, finest first (YOLO heads: 8, 16, 32);
* ``fuse()``: a fused copy in eval mode (``slimseg.layers.fuse``), ``self`` untouched;
* ``is_fused``: asked of the blocks' own state (``slimseg.layers.fuse.is_fused``);
* ``detection_rows(pred)`` (static): the eval output of a detector or segmenter → the one
  row layout NMS reads, ``[B, 4 + nc + nm, A]`` (``cx, cy, w, h`` in input pixels, class
  scores, mask coefficients); the identity unless a family's output differs;
* ``dead_conv_params()``: parameters the published code defines but never uses (0 unless a
  family says otherwise; counted only in the paper-comparable parameter column).

Eval-mode outputs per ``spec.task``: ``segment`` → ``(pred [B, 4 + nc + nm, A],
proto [B, nm, H/4, W/4])``; ``detect`` → ``pred [B, rows, A]``; ``semantic`` →
``logits [B, nc + 1, H, W]``.
"""

from __future__ import annotations

from typing import Self

import torch
from torch import nn

from slimseg.layers.fuse import fuse_model
from slimseg.layers.fuse import is_fused as blocks_fused
from slimseg.models.specs import ModelSpec


class ZooModel(nn.Module):
    """Base of every slimseg network (see the module docstring for the contract)."""

    strides: tuple[int, ...]

    def __init__(self, spec: ModelSpec) -> None:
        super().__init__()
        self.spec = spec
        self.num_classes = spec.num_classes

    @property
    def is_fused(self) -> bool:
        """True when every re-parameterizable block holds its fused structure."""
        return blocks_fused(self)

    def fuse(self) -> Self:
        """A fused copy (Conv+BN folded, RepConv merged) in eval mode; ``self`` is untouched."""
        return fuse_model(self)

    @staticmethod
    def detection_rows(pred: torch.Tensor) -> torch.Tensor:
        """``pred [B, 4 + nc + nm, A]`` as NMS reads it (already that layout here)."""
        return pred

    def dead_conv_params(self) -> int:
        """Parameters the published code defines but never calls (none by default)."""
        return 0
