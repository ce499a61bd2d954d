"""Export metadata: everything a runtime needs to use a model without hard-coded constants.

Stored as ONNX ``metadata_props`` (every value a JSON string) and as a sidecar ``NAME.json``
with the same content (TensorRT engines carry no metadata). ``export/CONTRACT.md`` documents
each key.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

from slimseg.dynamic.masking_settings import (
    DEFAULT,
    DEFAULT_PRESET,
    DILATION_REFERENCE_PX,
    PAPERS,
    PRESETS,
    MaskingSettings,
    SettingsError,
)
from slimseg.errors import SlimsegError
from slimseg.ops.letterbox import PAD_VALUE
from slimseg.ops.nms_numpy import MAX_DET, NMS_IOU, PREDICT_CONF
from slimseg.utils.text import printable
from slimseg.version import __version__

if TYPE_CHECKING:  # the runtime reads metadata without torch
    from slimseg.models.base import ZooModel

# Eq. 1's starting mobility threshold of the default masking settings (docs/papers.md §2):
# classes above it are dynamic. Read from slimseg.dynamic.masking_settings, never retyped.
DEFAULT_MOBILITY_THRESHOLD = DEFAULT.m_th_start
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


# The precision the contract's parity holds at, and what each engine computes by default
# (export/CONTRACT.md "Precision", docs/engines.md): one entry, the same in every file.
PARITY_ENTRY: dict[str, Any] = {
    "arithmetic": "fp32",
    "checked_with": "onnxruntime CPU float32 kernels on the file's own types (FP16 tensors in "
    "fp16, INT8 Q/DQ as written, the rest in fp32)",
    "engine_defaults": {
        "onnxruntime": "fp32",
        "openvino_x86_amx_or_avx512_bf16": "bf16: set INFERENCE_PRECISION_HINT=f32 "
        "(slimseg --backend openvino does)",
        "openvino_x86_other": "f32 (set INFERENCE_PRECISION_HINT=f32 anyway)",
        "openvino_arm": "f16: set INFERENCE_PRECISION_HINT=f32",
        "opencv_dnn": "fp32",
        "tensorrt": "fp16 where built with --fp16 (export/build_engine.sh on 8.6 / 10): build "
        "without it; strongly typed (11): the file's own types",
    },
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
        "recommended_mask_dilation_px": input_dilation_px(DEFAULT.dilation_px, imgsz),
        "slam_masking": slam_masking_entry(),
        "nms": {"conf": PREDICT_CONF, "iou": NMS_IOU, "max_det": MAX_DET, "class_aware": True},
        "parity": PARITY_ENTRY,
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


def input_dilation_px(dilation_px: int, imgsz: tuple[int, int]) -> int | float:
    """``dilation_px`` (frame pixels at a ``DILATION_REFERENCE_PX``-wide frame) in network
    input pixels, the unit of the ``recommended_mask_dilation_px`` key (a runtime multiplies
    it by ``max(h, w) / max(H, W)``): an int where exact, else rounded to 0.01 px."""
    v = dilation_px * max(int(imgsz[0]), int(imgsz[1])) / DILATION_REFERENCE_PX
    return int(v) if float(v).is_integer() else round(v, 2)


def slam_masking_entry() -> dict[str, Any]:
    """The ``slam_masking`` key: the default SLAM-facing settings (flat), the frame width the
    dilation refers to, and every named preset (docs/slam_defaults.md)."""
    return {
        "preset": DEFAULT_PRESET,
        **DEFAULT.as_dict(),
        "dilation_reference_px": DILATION_REFERENCE_PX,
        "presets": {name: s.as_dict() for name, s in PRESETS.items()},
    }


def masking_from_metadata(meta: dict[str, Any], preset: str | None = None) -> MaskingSettings:
    """The recommended SLAM-facing settings of an export: ``slam_masking`` where present;
    exports older than that key give the ``papers`` preset with their ``mobility_threshold``
    and ``recommended_mask_dilation_px`` (input pixels, converted back to frame pixels at a
    ``DILATION_REFERENCE_PX``-wide frame). ``preset``: one of ``slam_masking.presets`` by name
    instead. :class:`SlimsegError` on a malformed entry or an unknown preset."""
    entry = meta.get("slam_masking")
    if preset is not None:
        presets = entry.get("presets") if isinstance(entry, dict) else None
        if not isinstance(presets, dict) or preset not in presets:
            have = ", ".join(presets) if isinstance(presets, dict) else "none"
            raise SlimsegError(f"export metadata slam_masking.presets: no preset {preset!r} "
                               f"(it has: {have})")  # fmt: skip
        entry = presets[preset]
        if not isinstance(entry, dict):
            raise SlimsegError(f"export metadata slam_masking.presets.{preset}: not an object")
    try:
        if isinstance(entry, dict):
            names = MaskingSettings.__dataclass_fields__
            return PAPERS.with_values(**{k: v for k, v in entry.items() if k in names})
        values: dict[str, Any] = {}
        if "mobility_threshold" in meta:
            values["m_th_start"] = float(meta["mobility_threshold"])
        if "recommended_mask_dilation_px" in meta and "imgsz" in meta:
            side = max(int(v) for v in meta["imgsz"])
            px = float(meta["recommended_mask_dilation_px"]) * DILATION_REFERENCE_PX / side
            values["dilation_px"] = round(px)
        return PAPERS.with_values(**values)
    except (SettingsError, TypeError, ValueError) as e:
        raise SlimsegError(f"export metadata slam_masking / mobility_threshold: {e}") from None


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
        except (TypeError, ValueError, RecursionError):  # RecursionError: nested past reason
            meta[key] = value
    return meta


def read_onnx_metadata(path: str | Path, props: dict[str, str]) -> dict[str, Any]:
    """Parse ``metadata_props`` of the ONNX file ``path``; :class:`SlimsegError` unless slimseg
    wrote them. A missing ``mobility`` (older exports) becomes 1.0 per class; a malformed one
    is refused."""
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
    if mobility is None:  # exports older than the key: every class may move
        meta["mobility"] = [1.0] * len(names)
    elif not (
        isinstance(mobility, list)
        and len(mobility) == len(names)
        and all(isinstance(m, int | float) and 0 <= m <= 1 for m in mobility)
    ):
        raise SlimsegError(
            f"{path}: metadata 'mobility' must hold one number in [0, 1] per class of 'names' "
            f"({len(names)}), got {str(mobility)[:80]}; re-export it with slimseg export"
        )
    _check_entries(path, meta)
    return meta


# the end-to-end entry's keys: (kind, low, high, whether each bound is open)
_END2END_KEYS = {
    "conf": (float, 0.0, 1.0, (False, True)),
    "iou": (float, 0.0, 1.0, (True, False)),
    "max_det": (int, 1, 1 << 20, (False, False)),
}


def _check_entries(path: str | Path, meta: dict[str, Any]) -> None:
    """:class:`SlimsegError` naming ``path`` and the field unless the ``end2end`` entry (when
    present) holds exactly ``conf`` in [0, 1), ``iou`` in (0, 1] and a whole ``max_det`` >= 1,
    and ``int8.target`` (when present) is a plain lower-case name."""
    fix = "re-export it with slimseg export"
    if "end2end" in meta:
        e2e = meta["end2end"]
        keys = sorted(e2e) if isinstance(e2e, dict) else None
        if keys is None or not set(_END2END_KEYS) <= set(keys):
            shown = printable(str(keys)[:80])
            raise SlimsegError(f"{path}: metadata 'end2end' must be an object holding "
                               f"{', '.join(_END2END_KEYS)}; got {shown}; {fix}")  # fmt: skip
        for key, (kind, lo, hi, (open_lo, open_hi)) in _END2END_KEYS.items():
            v = e2e[key]
            ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            ok = ok and (kind is float or float(v).is_integer())
            ok = ok and (lo < v if open_lo else lo <= v) and (v < hi if open_hi else v <= hi)
            if not ok:
                raise SlimsegError(f"{path}: metadata end2end.{key} is {printable(repr(v)[:40])},"
                                   f" not a {kind.__name__} in {lo}-{hi}; {fix}")  # fmt: skip
    entry = meta.get("int8")
    target = entry.get("target") if isinstance(entry, dict) else None
    if target is not None and not (isinstance(target, str) and re.fullmatch(r"[a-z0-9_]{1,32}",
                                                                             target)):  # fmt: skip
        raise SlimsegError(f"{path}: metadata int8.target is {printable(repr(target)[:40])}, not "
                           f"a runtime's name; {fix}")  # fmt: skip


def with_end2end(meta: dict[str, Any], entry: dict[str, Any]) -> dict[str, Any]:
    """The metadata of an end-to-end export (``slimseg export --end2end``) made from the raw
    export's ``meta``: the ``end2end`` entry (``conf``, ``iou``, ``max_det`` baked into the
    graph), ``nms`` bounded by it and ``outputs`` describing the end-to-end tensors."""
    k = int(entry["max_det"])
    nms = dict(meta["nms"])
    nms.update(conf=max(float(nms["conf"]), float(entry["conf"])), iou=entry["iou"], max_det=k)
    outputs: dict[str, Any] = {
        "num_dets": {"shape": ["B"], "rows": "int32: valid rows of each image"},
        "boxes": {"shape": ["B", k, 4], "rows": "float32 x1, y1, x2, y2 in input px; 0 padding"},
        "scores": {"shape": ["B", k], "rows": "float32 best class score, decreasing; 0 padding"},
        "classes": {"shape": ["B", k], "rows": "int32 class index; -1 padding"},
    }
    if meta.get("num_masks"):
        stride = meta["proto_stride"]
        outputs["masks"] = {
            "shape": ["B", k, f"H/{stride}", f"W/{stride}"],
            "rows": "sigmoid(coefficients . prototypes), 0 outside the box grown by one "
            "prototype cell; upsample to the input, crop to the box, > 0.5, undo the letterbox",
        }
    return {**meta, "end2end": dict(entry), "nms": nms, "outputs": outputs}


def expected_outputs(meta: dict[str, Any]) -> dict[str, tuple[int, int | None]]:
    """``{output name: (rank, channels)}`` a graph with this metadata must have: channels
    (dim 1) from the class count of ``names`` and ``num_masks`` (see :func:`build_metadata`);
    end-to-end exports: their five tensors, dim 1 ``max_det``."""
    nc = len(meta["names"])
    if isinstance(meta.get("end2end"), dict):
        k = int(meta["end2end"]["max_det"])
        e2e = {"num_dets": (1, None), "boxes": (3, k), "scores": (2, k), "classes": (2, k)}
        return {**e2e, **({"masks": (4, k)} if meta.get("num_masks") else {})}
    if meta.get("task") == "semantic":
        return {"logits": (4, nc + 1)}
    if meta.get("family") == "darknet-yolov3":
        return {"output0": (3, 5 + nc)}
    nm = int(meta.get("num_masks", 0) or 0)
    return {"output0": (3, 4 + nc + nm), **({"output1": (4, nm)} if nm else {})}


def check_graph_outputs(path: str | Path, meta: dict[str, Any], graph: dict[str, list]) -> None:
    """:class:`SlimsegError` unless the graph's outputs (``graph``: name -> shape, a dim an
    int or a symbol) are those the metadata describes: each of :func:`expected_outputs`
    present with its rank and (where static) its channel count, and the metadata's own
    ``outputs`` entry naming the same ones."""
    expected = expected_outputs(meta)
    described = meta.get("outputs")
    if isinstance(described, dict) and set(described) != set(expected):
        raise SlimsegError(
            f"{path}: metadata 'outputs' names {sorted(described)}, but its task/family/"
            f"num_masks imply {sorted(expected)}; re-export it with slimseg export"
        )
    for name, (rank, channels) in expected.items():
        shape = graph.get(name)
        if shape is None:
            raise SlimsegError(
                f"{path}: the metadata describes output {name!r}, the graph has "
                f"{', '.join(sorted(graph)) or 'no outputs'}; re-export it with slimseg export"
            )
        dim = shape[1] if len(shape) > 1 and channels is not None else None
        if len(shape) != rank or (isinstance(dim, int) and dim != channels):
            raise SlimsegError(
                f"{path}: output {name!r} has shape {list(shape)}, the metadata "
                f"({len(meta['names'])} names) implies rank {rank} with {channels} channels; "
                "re-export it with slimseg export"
            )


def read_session_metadata(path: str | Path, session: Any) -> dict[str, Any]:
    """The slimseg metadata of the onnxruntime ``session`` of ``path``, checked against the
    graph's actual outputs (:func:`read_onnx_metadata`, :func:`check_graph_outputs`)."""
    meta = read_onnx_metadata(path, dict(session.get_modelmeta().custom_metadata_map))
    check_graph_outputs(path, meta, {o.name: list(o.shape) for o in session.get_outputs()})
    return meta


def int8_target(meta: dict[str, Any]) -> str | None:
    """The runtime an INT8 export is for (``int8.target``: ``tensorrt`` or ``onnxruntime``;
    INT8 files written before the key existed are TensorRT's); ``None`` unless INT8."""
    if meta.get("precision") != "int8":
        return None
    entry = meta.get("int8")
    target = entry.get("target") if isinstance(entry, dict) else None
    return str(target) if target else "tensorrt"


def precision_label(meta: dict[str, Any]) -> str:
    """``fp32``, ``fp16``, or ``int8, onnxruntime target`` / ``int8, tensorrt target``."""
    target = int8_target(meta)
    precision = str(meta.get("precision", "fp32"))
    label = f"{precision}, {target} target" if target else precision
    return printable(label)  # both come from the file: escaped for the terminal
