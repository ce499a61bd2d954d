"""An exported ONNX graph behind the interface the evaluator and predictor code expect of a
model (``spec``, ``num_classes``, ``forward``), so ``slimseg val`` scores the deployed file
with the same letterbox, NMS, mask assembly and pycocotools evaluator as the torch weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from slimseg.deploy.end2end_postprocess import is_end2end
from slimseg.deploy.engines import open_graph
from slimseg.deploy.runners import OnnxRunner
from slimseg.errors import SlimsegError
from slimseg.models.specs import ModelSpec, spec_from_mapping


class OnnxModel(nn.Module):
    """A slimseg ONNX export (FP32, FP16 or INT8) run on the CPU by onnxruntime or, with
    ``backend`` ``openvino`` (``openvino:bf16``, ...), by OpenVINO.

    ``forward(images float32 [B, 3, H, W])`` returns what the fused torch model returns:
    ``(pred [B, 4 + nc + nm, A], proto [B, nm, H/s, W/s])`` for segmenters, ``pred`` for
    detectors, ``logits [B, K + 1, H, W]`` for semantic models (float32 torch tensors; FP16
    graphs are fed float16). Static-batch graphs run in chunks of their batch size.
    """

    def __init__(
        self, path: str | Path, threads: int | None = None, backend: str = "onnxruntime"
    ) -> None:
        super().__init__()
        self.path = Path(path)
        if not self.path.is_file():
            raise SlimsegError(f"{self.path}: model file not found")
        session, self.metadata, self.backend = open_graph(self.path, threads, backend)
        if "spec" not in self.metadata:
            raise SlimsegError(
                f"{self.path}: its metadata has no 'spec': re-export it with slimseg export"
            )
        if is_end2end(self.metadata):
            raise SlimsegError(
                f"{self.path}: an end-to-end export (NMS inside, conf "
                f"{self.metadata['end2end']['conf']}); slimseg val scores the raw network at "
                "its own thresholds: give the export made without --end2end"
            )
        self.spec: ModelSpec = spec_from_mapping(
            ModelSpec, self.metadata["spec"], f"{self.path} metadata spec"
        )
        self.runner = OnnxRunner(session, str(self.path))
        self.num_classes = len(self.metadata["names"])
        self.precision = str(self.metadata.get("precision", "fp32"))

    @property
    def static_hw(self) -> tuple[int, int] | None:
        """The graph's static input ``(H, W)``; ``None`` for ``--dynamic`` exports."""
        return self.runner.static_hw

    def forward(self, images: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        x = np.ascontiguousarray(images.detach().cpu().float().numpy())
        pred, proto = self.runner.run_chunked(x)
        if proto is None:
            return torch.from_numpy(pred)
        return torch.from_numpy(pred), torch.from_numpy(proto)
