"""The end-to-end post-processing sub-graph: decode, class-aware NMS, top-``max_det``, masks.

Appended with ``onnx.helper`` to a raw YOLOv8 export (``output0 [B, 4 + nc + nm, A]``,
``output1 [B, nm, Hp, Wp]``), in standard ``ai.onnx`` operators only, so a runtime loads the
file as it is (export/CONTRACT.md "End-to-end exports"). The raw outputs are replaced by:

- ``num_dets int32 [B]``: detections of each image (the first ``num_dets`` rows are valid);
- ``boxes float32 [B, K, 4]``: ``x1, y1, x2, y2`` in network-input pixels (0 in padding);
- ``scores float32 [B, K]``: best class score, decreasing (0 in padding);
- ``classes int32 [B, K]``: class index (-1 in padding);
- ``masks [B, K, Hp, Wp]`` (segmenters): ``sigmoid(coefficients · prototypes)`` at prototype
  resolution, 0 outside the box grown by one prototype cell (``proto_stride`` input pixels on
  each side, so the contract's upsampling and crop to the box give the raw path's masks
  exactly); float32, float16 in FP16 files.

``K`` = ``max_det``. Steps: best class per anchor (the first on a tie) as in
:func:`slimseg.ops.nms_numpy.nms_rows`; one ``NonMaxSuppression`` (``score > conf``,
suppression at ``IoU > iou``, at most ``max_det``) on the best scores with each box shifted by
``class × span`` (span: 1 + the extent of the candidates' coordinates), so that boxes of
different classes never overlap (class-aware, as the raw path's ``batched_nms``); the
survivors' scores scattered back per anchor and the ``max_det`` best taken with ``TopK``;
boxes, classes and mask coefficients gathered at those anchors; masks computed for the rows up
to the largest ``num_dets`` of the batch, cropped by products with 1-D row and column masks,
then padded once. FP16 files: ``output0`` is cast to float32 before the
decode, so the boxes, scores, NMS and TopK run in FP32; the mask product, sigmoid and crop run
in FP16 on the FP16 prototypes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from slimseg.deploy.end2end_postprocess import END2END_OUTPUTS
from slimseg.dynamic.masking_settings import DEFAULT
from slimseg.errors import SlimsegError
from slimseg.ops.nms_numpy import NMS_IOU, PREDICT_CONF

PREFIX = "e2e/"
# the graph keeps what every default consumer asks for: predict (0.25) and SLAM masking (0.1)
DEFAULT_END2END_CONF = min(PREDICT_CONF, DEFAULT.conf)
DEFAULT_END2END_IOU = NMS_IOU
# K, the rows per image: the masks output is [B, K, H/s, W/s] whatever the frame holds (its
# padding rows are written every frame: 300 rows of 160 x 160 at 640 px are 30 MB), and a SLAM
# frame holds tens of instances (7-31 on the demo's frames at conf 0.1); 100 leaves room and
# keeps the end-to-end path at or below the raw path's time (docs/end2end.md "Latency")
DEFAULT_END2END_MAX_DET = 100


@dataclass(frozen=True)
class End2EndSettings:
    """What the sub-graph bakes in: ``conf`` (keep ``score > conf``), ``iou`` (suppress at
    ``IoU > iou``), ``max_det`` (``K``, rows per image) and ``proto_stride`` (input pixels per
    prototype cell, the crop margin)."""

    conf: float
    iou: float
    max_det: int
    proto_stride: int = 4

    def as_dict(self) -> dict:
        """The ``end2end`` metadata entry."""
        return {
            "conf": self.conf,
            "iou": self.iou,
            "max_det": self.max_det,
            "class_aware": True,
            "mask_margin_px": self.proto_stride,
        }


class _Builder:
    """Nodes and constants appended to a graph under unique ``e2e/`` names."""

    def __init__(self, graph: onnx.GraphProto, opset: int) -> None:
        self.graph = graph
        self.opset = opset
        self.count = 0

    def name(self, hint: str) -> str:
        self.count += 1
        return f"{PREFIX}{hint}_{self.count}"

    def const(self, value: np.ndarray | list | float | int, dtype=np.int64) -> str:
        name = self.name("c")
        self.graph.initializer.append(numpy_helper.from_array(np.asarray(value, dtype), name))
        return name

    def op(self, op_type: str, inputs: list[str], n_out: int = 1, **attrs) -> list[str]:
        outs = [self.name(op_type.lower()) for _ in range(n_out)]
        node = helper.make_node(op_type, inputs, outs, name=self.name(op_type), **attrs)
        self.graph.node.append(node)
        return outs

    def one(self, op_type: str, *inputs: str, **attrs) -> str:
        return self.op(op_type, list(inputs), **attrs)[0]

    def reduce_max(self, x: str, axis: int, keepdims: int) -> str:
        """``ReduceMax`` over ``axis``: its axes are an input from opset 18, an attribute
        before (``--opset 17``)."""
        if self.opset >= 18:
            return self.one("ReduceMax", x, self.const([axis]), keepdims=keepdims)
        return self.one("ReduceMax", x, axes=[axis], keepdims=keepdims)

    def slice(self, x: str, start: int, end: int, axis: int) -> str:
        return self.one("Slice", x, self.const([start]), self.const([end]), self.const([axis]))

    def output(self, name: str, op_type: str, *inputs: str, **attrs) -> str:
        """The graph output ``name`` written by its own node (no ``Identity``: an engine that
        folds an ``Identity`` gives its output the folded tensor's internal names too)."""
        node = helper.make_node(op_type, list(inputs), [name], name=self.name(op_type), **attrs)
        self.graph.node.append(node)
        return name

    def static_output(self, name: str, x: str, dims: list[int], always: bool = False) -> str:
        """``x`` reshaped to ``dims`` (0: the dimension as it is, a dynamic one) as the graph
        output ``name``: the static dimensions stated in the graph, where an engine's shape
        inference cannot follow a data-dependent ``Pad`` (OpenVINO: ``masks [?,?,?,?]``) or
        ``TopK`` (``[?, K]`` in dynamic files). Without a 0 in ``dims`` and unless ``always``,
        ``x``'s producer is renamed instead: an engine drops a no-op ``Reshape`` and would give
        the output ``x``'s internal name too."""
        if always or 0 in dims:
            return self.output(name, "Reshape", x, self.const(dims))
        (producer,) = [n for n in self.graph.node if x in n.output]
        producer.output[list(producer.output).index(x)] = name
        return name


def _output_type(proto: onnx.ModelProto, name: str) -> int:
    for o in proto.graph.output:
        if o.name == name:
            return o.type.tensor_type.elem_type
    raise SlimsegError(f"end-to-end export: the raw graph has no output {name!r}")


def append_end2end(
    proto: onnx.ModelProto,
    nc: int,
    nm: int,
    settings: End2EndSettings,
    batch: int | str,
    anchors: int | None = None,
) -> onnx.ModelProto:
    """``proto`` (a raw YOLOv8 export, modified in place and returned) with the post-processing
    sub-graph of the module docstring; ``nc`` classes, ``nm`` mask coefficients (0: detector);
    ``batch``: the static batch size or the name of the dynamic axis; ``anchors``: ``A`` of a
    static input size (``None``: dynamic H, W)."""
    if settings.max_det < 1:
        raise SlimsegError(f"--max-det {settings.max_det}: need at least 1")
    opset = next(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx"))
    g, b = proto.graph, _Builder(proto.graph, opset)
    float_type = _output_type(proto, "output0")
    raw = "output0"
    pred = raw if float_type == TensorProto.FLOAT else b.one("Cast", raw, to=TensorProto.FLOAT)
    # decode: boxes [B, A, 4] xyxy, best score [B, A], best class [B, 1, A]
    xy, wh = b.slice(pred, 0, 2, 1), b.slice(pred, 2, 4, 1)
    half = b.one("Div", wh, b.const(2.0, np.float32))
    xyxy = b.one("Concat", b.one("Sub", xy, half), b.one("Add", xy, half), axis=1)
    boxes = b.one("Transpose", xyxy, perm=[0, 2, 1])
    cls = b.slice(pred, 4, 4 + nc, 1)  # [B, nc, A]
    arg = b.one("ArgMax", cls, axis=1, keepdims=1, select_last_index=0)  # [B, 1, A]
    best3 = b.one("GatherElements", cls, arg, axis=1)  # [B, 1, A]: the max, read at arg
    best = b.one("Squeeze", best3, b.const([1]))  # [B, A]
    # class-aware NMS in one pass, as the raw path's batched_nms: each class's boxes shifted
    # by class x span, span > the extent of the candidates' coordinates (score > conf, and 0),
    # so that boxes of different classes never overlap
    cand = b.one("Greater", best, b.const(settings.conf, np.float32))  # [B, A]
    cand = b.one("Unsqueeze", b.one("Cast", cand, to=TensorProto.FLOAT), b.const([2]))
    coords = b.one("Mul", boxes, cand)  # [B, A, 4]: 0 for the other anchors
    top = b.reduce_max(b.reduce_max(coords, 1, 1), 2, 1)  # [B, 1, 1]
    neg = b.one("Mul", coords, b.const(-1.0, np.float32))
    bottom = b.reduce_max(b.reduce_max(neg, 1, 1), 2, 1)  # -min
    span = b.one("Add", b.one("Add", top, bottom), b.const(1.0, np.float32))
    group = b.one("Cast", b.one("Transpose", arg, perm=[0, 2, 1]), to=TensorProto.FLOAT)
    shift = b.one("Mul", group, span)  # [B, A, 1]
    selected = b.one(
        "NonMaxSuppression",
        b.one("Add", boxes, shift),
        best3,
        b.const([settings.max_det]),
        b.const([settings.iou], np.float32),
        b.const([settings.conf], np.float32),
        center_point_box=0,
    )  # [N, 3]: batch, class (0), anchor
    pairs = b.one("Concat", b.slice(selected, 0, 1, 1), b.slice(selected, 2, 3, 1), axis=1)
    kept = b.one("GatherND", best, pairs)  # [N]
    empty = b.one("Sub", b.one("Mul", best, b.const(0.0, np.float32)), b.const(1.0, np.float32))
    grid = b.one("ScatterND", empty, pairs, kept)  # [B, A]: survivors' scores, -1 elsewhere
    if anchors is None:  # dynamic H, W: K = min(A, max_det) from the shape
        count_a = b.one("Gather", b.one("Shape", grid), b.const([1]), axis=0)
        k = b.one("Min", count_a, b.const([settings.max_det]))
        pad = b.one("Sub", b.const([settings.max_det]), k)
    else:  # static: constants (TensorRT's TopK takes K as an initializer)
        k = b.const([min(anchors, settings.max_det)])
        pad = b.const([settings.max_det - min(anchors, settings.max_det)])
    top_v, top_i = b.op("TopK", [grid, k], n_out=2, axis=1, largest=1, sorted=1)
    pads = b.one("Concat", b.const([0, 0, 0]), pad, axis=0)
    top_v = b.one("Pad", top_v, pads, b.const(-1.0, np.float32))  # [B, K]
    top_i = b.one("Pad", top_i, pads, b.const(0))
    valid = b.one("Greater", top_v, b.const(-0.5, np.float32))  # [B, K]
    # Each output is written by a node no engine folds away, and nothing else reads it: an
    # engine that drops a no-op node (a Cast, an Identity, a Reshape) gives the survivor both
    # tensors' names, and OpenVINO's get_any_name() then picks the internal one. num_dets is
    # summed in int32 (a Cast after an int64 sum is such a node), the mask rows count apart.
    k_rows, bdim = settings.max_det, batch if isinstance(batch, int) else 0
    valid32 = b.one("Cast", valid, to=TensorProto.INT32)
    b.output("num_dets", "ReduceSum", valid32, b.const([1]), keepdims=0)
    count = b.one("ReduceSum", b.one("Cast", valid, to=TensorProto.INT64), b.const([1]), keepdims=0)
    scores = b.one("Where", valid, top_v, b.const(0.0, np.float32))
    b.static_output("scores", scores, [bdim, k_rows])
    at = b.one("Unsqueeze", top_i, b.const([2]))  # [B, K, 1]
    valid3 = b.one("Unsqueeze", valid, b.const([2]))
    picked = b.one("GatherND", boxes, at, batch_dims=1)
    b.static_output("boxes", b.one("Where", valid3, picked, b.const(0.0, np.float32)),
                    [bdim, k_rows, 4])  # fmt: skip
    classes = b.one("GatherElements", b.one("Squeeze", arg, b.const([1])), top_i, axis=1)
    classes = b.one("Where", valid, b.one("Cast", classes, to=TensorProto.INT32),
                    b.const(-1, np.int32))  # fmt: skip
    b.static_output("classes", classes, [bdim, k_rows])
    names = END2END_OUTPUTS[:4]
    if nm:
        mask_hw = _proto_hw(g)
        _append_masks(b, raw, nc, nm, settings, boxes, top_i, valid, count, float_type, bdim,
                      mask_hw)  # fmt: skip
        names = END2END_OUTPUTS
    _set_outputs(g, names, settings.max_det, batch, float_type)
    return proto


def _append_masks(
    b: _Builder,
    raw: str,
    nc: int,
    nm: int,
    settings: End2EndSettings,
    boxes: str,
    top_i: str,
    valid: str,
    count: str,
    float_type: int,
    bdim: int,
    mask_hw: list[int],
) -> None:
    """``masks [B, K, Hp, Wp]``: the rows up to the batch's largest ``num_dets`` computed,
    the rest zero padding; ``bdim`` and ``mask_hw``: the static batch and ``Hp, Wp`` (0 where
    dynamic)."""
    dtype = np.float16 if float_type == TensorProto.FLOAT16 else np.float32
    rows = b.reduce_max(count, 0, keepdims=1)  # [1]
    top_k = b.one("Slice", top_i, b.const([0]), rows, b.const([1]))  # [B, k]
    valid_k = b.one("Slice", valid, b.const([0]), rows, b.const([1]))
    at = b.one("Unsqueeze", top_k, b.const([2]))
    # the kept anchors' coefficients read in place ([B, nm, A] is not transposed whole)
    cols = b.one("Add", b.one("Unsqueeze", top_k, b.const([1])), b.const(np.zeros((1, nm, 1))))
    coeffs = b.one("GatherElements", b.slice(raw, 4 + nc, 4 + nc + nm, 1), cols, axis=2)
    coeffs = b.one("Transpose", coeffs, perm=[0, 2, 1])  # [B, k, nm]
    flat = b.one("Reshape", "output1", b.const([0, nm, -1]))  # [B, nm, Hp * Wp]
    probs = b.one("Sigmoid", b.one("MatMul", coeffs, flat))  # [B, k, Hp * Wp]
    proto_shape = b.one("Shape", "output1")
    shape = b.one(
        "Concat",
        b.one("Slice", b.one("Shape", probs), b.const([0]), b.const([2])),
        b.one("Slice", proto_shape, b.const([2]), b.const([4])),
        axis=0,
    )
    probs = b.one("Reshape", probs, shape)  # [B, k, Hp, Wp]
    # prototype cell centres in input pixels, the box grown by one cell
    s = float(settings.proto_stride)
    box_k = b.one("GatherND", boxes, at, batch_dims=1)  # [B, k, 4]
    box_k = b.one("Unsqueeze", box_k, b.const([3]))  # [B, k, 4, 1]
    inside = []
    for axis, (lo, hi) in ((2, (1, 3)), (3, (0, 2))):
        size = b.one("Gather", proto_shape, b.const([axis]), axis=0)
        cells = b.one("Range", b.const(0), b.one("Squeeze", size, b.const([0])), b.const(1))
        centre = b.one(
            "Mul",
            b.one("Add", b.one("Cast", cells, to=TensorProto.FLOAT), b.const(0.5, np.float32)),
            b.const(s, np.float32),
        )  # [n]
        first = b.one("Sub", b.slice(box_k, lo, lo + 1, 2), b.const(s, np.float32))
        last = b.one("Add", b.slice(box_k, hi, hi + 1, 2), b.const(s, np.float32))
        ok = b.one(
            "And", b.one("GreaterOrEqual", centre, first), b.one("LessOrEqual", centre, last)
        )  # [B, k, 1, n]
        if axis == 2:  # rows: [B, k, Hp, 1], the padding rows of a batch cleared here
            ok = b.one("Transpose", ok, perm=[0, 1, 3, 2])
            ok = b.one("And", ok, b.one("Unsqueeze", valid_k, b.const([2, 3])))
        inside.append(b.one("Cast", ok, to=float_type))
    # the crop as two broadcast products with the 1-D row and column masks (1 or 0): no
    # [B, k, Hp, Wp] boolean is materialised
    masks = b.one("Mul", b.one("Mul", probs, inside[0]), inside[1])
    pad_rows = b.one("Sub", b.const([settings.max_det]), rows)
    pads = b.one("Concat", b.const([0, 0, 0, 0, 0]), pad_rows, b.const([0, 0]), axis=0)
    padded = b.one("Pad", masks, pads, b.const(0.0, dtype))
    b.static_output("masks", padded, [bdim, settings.max_det, *mask_hw], always=True)


def _proto_hw(g: onnx.GraphProto) -> list[int]:
    """``[Hp, Wp]`` of ``output1`` as the raw graph declares them, 0 for a dynamic one."""
    dims = [d for o in g.output if o.name == "output1" for d in o.type.tensor_type.shape.dim]
    return [int(d.dim_value) for d in dims[2:4]] if len(dims) == 4 else [0, 0]


def _set_outputs(
    g: onnx.GraphProto, names: tuple[str, ...], k: int, batch: int | str, float_type: int
) -> None:
    """Replace the raw outputs by ``names`` with their contract shapes and types."""
    mask_dims = [d for o in g.output if o.name == "output1" for d in o.type.tensor_type.shape.dim]
    hw = [d.dim_value or d.dim_param for d in mask_dims[2:]] or ["mask_height", "mask_width"]
    specs = {
        "num_dets": (TensorProto.INT32, [batch]),
        "boxes": (TensorProto.FLOAT, [batch, k, 4]),
        "scores": (TensorProto.FLOAT, [batch, k]),
        "classes": (TensorProto.INT32, [batch, k]),
        "masks": (float_type, [batch, k, *hw]),
    }
    del g.output[:]
    for name in names:
        dtype, shape = specs[name]
        g.output.append(helper.make_tensor_value_info(name, dtype, shape))
