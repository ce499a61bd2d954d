"""Where an INT8 export puts its Q/DQ pairs: which nodes of the fused ONNX graph run in INT8.

Two rules, one per deployment target (``slimseg export --int8-target``), both defined for the
YOLOv8 family only (all ``yolov8*`` variants).

**tensorrt** (:func:`plan_placement`): convolutions only; TensorRT fuses the activations
itself.

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

**onnxruntime** (:func:`plan_placement_ort`): onnxruntime's CPU kernels run a whole chain of
quantized operators (``QLinearConv`` → ``QLinearSigmoid`` → ``QLinearMul`` …) without
returning to float, so every operator of the network body is quantized, not only the
convolutions:

* **INT8**: every node of backbone and neck (convolutions including the first one, SiLU's
  Sigmoid and Mul, Concat, Split, Add, MaxPool, Resize, GSConv's shuffles), and every
  Conv+BN+act block of the head with its activation (box/class stems, the shared RepConv,
  the mask-coefficient towers, the prototype convs and the prototype ``ConvTranspose``).
* **Floating point**: the head's output end, from the plain predictor convs (box, class and
  mask-coefficient outputs) on: DFL, box decode, class sigmoid, the output concats; their
  values are the detections themselves (an 8-bit box-distribution or class logit moves boxes
  and scores), and quantizing them saves no measurable time. GSConv's depthwise blocks
  follow :data:`ORT_QUANTIZE_DEPTHWISE`.

Both choices were made by measuring speed side by side and mAP (``docs/int8.md``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import onnx

from slimseg.errors import SlimsegError

# Families whose graphs this rule knows.
INT8_FAMILIES = ("yolov8",)
# Deployment targets of an INT8 file (docs/int8.md: which file for which runtime).
INT8_TARGETS = ("tensorrt", "onnxruntime")
DEFAULT_INT8_TARGET = "tensorrt"
# Depthwise 5x5 convs of GSConv in INT8? Chosen by measurement (docs/int8.md).
QUANTIZE_DEPTHWISE = False
# Depthwise convs in INT8 for the onnxruntime target? Chosen by measurement (docs/int8.md).
ORT_QUANTIZE_DEPTHWISE = False
# A Conv+BN+act block's convolution in the exported graph (``_N``: a shared module's N-th call).
_BLOCK_CONV = re.compile(r"/conv(_\d+)?/Conv$")
# A Conv+BN+act block's nodes: its convolution and its SiLU (Sigmoid, Mul).
_BLOCK_NODE = re.compile(r"/(conv(_\d+)?/Conv|act(_\d+)?/(Sigmoid|Mul))$")
# Scopes whose every node is network body (the head's output end lives elsewhere).
_BODY_SCOPES = ("/backbone/", "/neck/")


@dataclass
class Placement:
    """``quantize``: names of the nodes that get Q/DQ (Conv nodes only for TensorRT);
    ``keep``: node name → why it stays in floating point (TensorRT: every other
    Conv/ConvTranspose; onnxruntime: every other node); ``ops``: quantized nodes per op type
    (onnxruntime target only)."""

    quantize: list[str] = field(default_factory=list)
    keep: dict[str, str] = field(default_factory=dict)
    ops: dict[str, int] = field(default_factory=dict)

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


def _is_depthwise(node: onnx.NodeProto, dims: dict[str, list[int]]) -> bool:
    weight = dims.get(node.input[1], []) if len(node.input) > 1 else []
    return node.op_type == "Conv" and _group(node) > 1 and len(weight) == 4 and weight[1] == 1


def _in_body(node: onnx.NodeProto) -> bool:
    return (
        node.name.startswith(_BODY_SCOPES)
        or bool(_BLOCK_NODE.search(node.name))
        or node.op_type == "ConvTranspose"
    )


def plan_placement_ort(
    model: onnx.ModelProto, family: str, quantize_depthwise: bool = ORT_QUANTIZE_DEPTHWISE
) -> Placement:
    """The onnxruntime target's :class:`Placement` (see the module doc): ``quantize`` names
    every node (of any op type) that gets quantized inputs and outputs; ``keep`` every other
    node with the reason; ``ops`` counts the quantized nodes per op type."""
    check_family(family, model.graph.name or "this model")
    dims = _initializer_dims(model.graph)
    # a float depthwise conv keeps its block's SiLU in float too (no Q/DQ round trip)
    float_blocks = [
        n.name.rsplit("/conv", 1)[0] + "/"
        for n in model.graph.node
        if not quantize_depthwise and _is_depthwise(n, dims)
    ]
    plan = Placement()
    for node in model.graph.node:
        if not _in_body(node):
            plan.keep[node.name] = "head output (predictors, DFL, decode)"
        elif float_blocks and node.name.startswith(tuple(float_blocks)):
            plan.keep[node.name] = "depthwise conv"
        else:
            plan.quantize.append(node.name)
            plan.ops[node.op_type] = plan.ops.get(node.op_type, 0) + 1
    if not plan.ops.get("Conv"):
        raise SlimsegError(
            "--int8: no backbone/neck/Conv+BN+act nodes found in the graph (were node names "
            "changed?); export with slimseg export, which keeps the module names"
        )
    return plan


def plan_for_target(
    model: onnx.ModelProto, family: str, target: str = DEFAULT_INT8_TARGET
) -> Placement:
    """The placement rule of ``target`` (one of :data:`INT8_TARGETS`)."""
    check_target(target)
    if target == "onnxruntime":
        return plan_placement_ort(model, family)
    return plan_placement(model, family)


def check_target(target: str) -> None:
    """:class:`SlimsegError` unless ``target`` is one of :data:`INT8_TARGETS`."""
    if target not in INT8_TARGETS:
        raise SlimsegError(f"--int8-target {target}: choose one of {', '.join(INT8_TARGETS)}")
