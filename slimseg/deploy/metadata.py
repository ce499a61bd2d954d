"""Export metadata: everything a runtime needs to use a model without hard-coded constants.

Stored as ONNX ``metadata_props`` (every value a JSON string) and as a sidecar ``NAME.json``
with the same content (TensorRT engines carry no metadata). ``export/CONTRACT.md`` documents
each key.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from slimseg import __version__
from slimseg.data.letterbox import PAD_VALUE
from slimseg.dynamic.threshold import M_TH_START
from slimseg.errors import SlimsegError
from slimseg.models.base import ZooModel
from slimseg.ops.nms import MAX_DET, NMS_IOU, PREDICT_CONF

# Eq. 1's mobility threshold at its starting value (docs/papers.md §2): classes above it are
# dynamic. Read from the SLAM-side code that applies it, never retyped.
DEFAULT_MOBILITY_THRESHOLD = M_TH_START
# Masks from 1/4- (or 1/2-) resolution prototypes are soft at the edges: dilate them before dropping
# keypoints (ORB's 31-px patch straddles the edge otherwise). Pixels at the 640 input.
RECOMMENDED_MASK_DILATION_PX = 5
# Keys every slimseg export carries and a runtime cannot do without.
REQUIRED_METADATA = ("names", "imgsz", "family", "task")

LETTERBOX_RULE = {
    "centered": True,
    "pad_value": PAD_VALUE,
    "scale": "min(H_in / h, W_in / w)",
    "resized_size": "new_w = floor(w * scale + 0.5), new_h = floor(h * scale + 0.5)",
    "padding": "left = (W_in - new_w) // 2, top = (H_in - new_h) // 2 (odd pixel right/bottom)",
    "interpolation": "bilinear (cv2.INTER_LINEAR)",
    "inverse": "x_frame = (x_input - left) / scale, y_frame = (y_input - top) / scale",
}


def build_metadata(
    model: ZooModel,
    names: list[str],
    mobility: list[float],
    imgsz: tuple[int, int],
    precision: str = "fp32",
    dynamic: bool = False,
) -> dict[str, Any]:
    """The metadata dict of an exported model (values are JSON-serialisable)."""
    spec = model.spec
    nc = spec.num_classes
    if len(names) != nc:
        names = [f"class{i}" for i in range(nc)]
    if len(mobility) != nc:
        mobility = [1.0] * nc
    dynamic_classes = [i for i, m in enumerate(mobility) if m > DEFAULT_MOBILITY_THRESHOLD]
    meta: dict[str, Any] = {
        "model": spec.name,
        "spec_hash": spec.hash,
        "spec": spec.to_dict(),
        "slimseg_version": __version__,
        "task": spec.task,
        "family": spec.family,
        "names": list(names),
        "mobility": [float(m) for m in mobility],
        "mobility_threshold": DEFAULT_MOBILITY_THRESHOLD,
        "dynamic_classes": dynamic_classes,
        "imgsz": [int(imgsz[0]), int(imgsz[1])],
        "strides": list(model.strides),
        "precision": precision,
        "dynamic_shapes": dynamic,
        "input": {
            "name": "images",
            "layout": "NCHW",
            "dtype": "float16" if precision == "fp16" else "float32",
            "color": "RGB",
            "scale": 1 / 255,
            "mean": [0.0, 0.0, 0.0],
            "std": [1.0, 1.0, 1.0],
        },
        "letterbox": LETTERBOX_RULE,
        "recommended_mask_dilation_px": RECOMMENDED_MASK_DILATION_PX,
        "nms": {"conf": PREDICT_CONF, "iou": NMS_IOU, "max_det": MAX_DET, "class_aware": True},
    }
    if spec.task == "semantic":
        del meta["nms"], meta["recommended_mask_dilation_px"]
        meta["outputs"] = {
            "logits": {
                "shape": ["B", nc + 1, "H", "W"],
                "rows": f"per-pixel class logits at the input resolution: channel 0 = "
                f"background, channel k + 1 = names[k] ({nc} classes); class map = argmax "
                "over channels (softmax for probabilities)",
            }
        }
        return meta
    if spec.family == "darknet-yolov3":
        meta["outputs"] = {
            "output0": {
                "shape": ["B", 5 + nc, "A"],
                "rows": "cx, cy, w, h (input px), objectness (sigmoid), nc class probabilities "
                "(sigmoid); score = objectness * class probability",
                "anchor_order": "level (stride 8, 16, 32) -> anchor (3) -> cell (row-major)",
            }
        }
        return meta
    nm = spec.head.num_masks if spec.task == "segment" else 0
    meta["num_masks"] = nm
    stride = spec.head.proto_stride
    if nm:
        meta["proto_stride"] = stride
    meta["outputs"] = {
        "output0": {
            "shape": ["B", 4 + nc + nm, "A"],
            "rows": f"cx, cy, w, h (input px), {nc} class scores (sigmoid), {nm} raw mask "
            "coefficients",
            "anchor_order": "level (stride 8, 16, 32) -> cell (row-major)",
        }
    }
    if nm:
        meta["outputs"]["output1"] = {
            "shape": ["B", nm, f"H/{stride}", f"W/{stride}"],
            "rows": "raw prototypes; mask = sigmoid(coefficients . prototypes), crop to the box, "
            "upsample to the input, > 0.5, then undo the letterbox",
        }
    return meta


def to_metadata_props(meta: dict[str, Any]) -> dict[str, str]:
    """ONNX ``metadata_props``: every value JSON-encoded (strings too, so parsing is uniform)."""
    return {key: json.dumps(value) for key, value in meta.items()}


def from_metadata_props(props: dict[str, str]) -> dict[str, Any]:
    """Inverse of ``to_metadata_props``; a value that is not JSON (another tool's) stays a
    string, so :func:`read_onnx_metadata` can say what is missing."""
    meta: dict[str, Any] = {}
    for key, value in props.items():
        try:
            meta[key] = json.loads(value)
        except (TypeError, ValueError):
            meta[key] = value
    return meta


def read_onnx_metadata(path: str | Path, props: dict[str, str]) -> dict[str, Any]:
    """Parse ``metadata_props`` of the ONNX file ``path``; :class:`SlimsegError` unless slimseg
    wrote them. A missing or malformed ``mobility`` becomes 1.0 per class."""
    meta = from_metadata_props(props)
    missing = [k for k in REQUIRED_METADATA if k not in meta]
    names, imgsz = meta.get("names"), meta.get("imgsz")
    if (
        missing
        or not isinstance(names, list)
        or not all(isinstance(n, str) for n in names)
        or not (isinstance(imgsz, list) and len(imgsz) == 2)
    ):
        what = f"missing {', '.join(missing)}" if missing else "malformed names/imgsz"
        raise SlimsegError(
            f"{path}: no slimseg metadata ({what}): not exported by slimseg export; "
            "re-export it with `slimseg export --weights W.pt`, or predict from the .pt weights"
        )
    mobility = meta.get("mobility")
    if not isinstance(mobility, list) or len(mobility) != len(names):
        meta["mobility"] = [1.0] * len(names)
    return meta
