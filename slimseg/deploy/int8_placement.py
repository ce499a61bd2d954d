"""Where an INT8 export puts its Q/DQ pairs: which Conv nodes of the fused ONNX graph run in INT8.

Rule for the YOLOv8 family (all ``yolov8*`` variants; the only family it is defined for):

* **INT8**: every convolution of a Conv+BN+act block (:class:`~slimseg.layers.conv.ConvBNAct`,
  the fused RepConv): the convolution towers of backbone, neck (GSConv's dense convs,
  VoVGSCSP) and head (box/class/mask-coefficient stems, the shared RepConv, the prototype
  convs). In the exported graph these are the ``Conv`` nodes named ``…/conv/Conv`` (or
  ``…/conv_N/Conv`` when a shared module runs once per level).
* **Floating point**: the first convolution (it sees the raw image), the plain predictor convs
  (box, class and mask-coefficient outputs, no BatchNorm, no activation), the DFL projection,
  and every non-Conv op: the prototype ``ConvTranspose``, sigmoids and SiLU multiplies,
  box decode, concats, reshapes. The GSConv 5×5 depthwise convs stay in floating point too
  when :data:`QUANTIZE_DEPTHWISE` is false (the measurement behind it is in ``docs/int8.md``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import onnx

from slimseg.errors import SlimsegError

# Families whose graphs this rule knows.
INT8_FAMILIES = ("yolov8",)
# Depthwise 5x5 convs of GSConv in INT8? Chosen by measurement (docs/int8.md).
QUANTIZE_DEPTHWISE = False
# A Conv+BN+act block's convolution in the exported graph (``_N``: a shared module's N-th call).
_BLOCK_CONV = re.compile(r"/conv(_\d+)?/Conv$")


@dataclass
class Placement:
    """``quantize``: names of the Conv nodes that get Q/DQ; ``keep``: node name → why it stays
    in floating point (every other Conv/ConvTranspose of the graph)."""

    quantize: list[str] = field(default_factory=list)
    keep: dict[str, str] = field(default_factory=dict)

    def summary(self) -> dict[str, int]:
        """Counts per decision, for metadata and logs."""
        counts: dict[str, int] = {"int8": len(self.quantize)}
        for reason in self.keep.values():
            counts[reason] = counts.get(reason, 0) + 1
        return counts


def check_family(family: str, model_name: str) -> None:
    """:class:`SlimsegError` unless the placement rule knows ``family``."""
    if family not in INT8_FAMILIES:
        raise SlimsegError(
            f"--int8: no INT8 placement for {model_name} (family {family}); it is defined for "
            f"{', '.join(INT8_FAMILIES)}: export this model in FP32 or FP16 (--half) instead"
        )


def _initializer_dims(graph: onnx.GraphProto) -> dict[str, list[int]]:
    return {t.name: list(t.dims) for t in graph.initializer}


def _group(node: onnx.NodeProto) -> int:
    for attr in node.attribute:
        if attr.name == "group":
            return int(attr.i)
    return 1


def plan_placement(
    model: onnx.ModelProto, family: str, quantize_depthwise: bool = QUANTIZE_DEPTHWISE
) -> Placement:
    """The :class:`Placement` of a fused slimseg graph of ``family`` (see the module doc)."""
    check_family(family, model.graph.name or "this model")
    graph_inputs = {i.name for i in model.graph.input}
    dims = _initializer_dims(model.graph)
    plan = Placement()
    for node in model.graph.node:
        if node.op_type == "ConvTranspose":
            plan.keep[node.name] = "prototype upsample (ConvTranspose)"
            continue
        if node.op_type != "Conv":
            continue
        weight = dims.get(node.input[1], [])
        depthwise = _group(node) > 1 and len(weight) == 4 and weight[1] == 1
        if node.input[0] in graph_inputs:
            plan.keep[node.name] = "first conv"
        elif not _BLOCK_CONV.search(node.name):
            plan.keep[node.name] = "predictor or DFL conv"
        elif depthwise and not quantize_depthwise:
            plan.keep[node.name] = "depthwise conv"
        else:
            plan.quantize.append(node.name)
    if not plan.quantize:
        raise SlimsegError(
            "--int8: no Conv+BN+act convolutions found in the graph (were node names changed?); "
            "export with slimseg export, which keeps the module names"
        )
    return plan
