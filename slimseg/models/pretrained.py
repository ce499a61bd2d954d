"""Initialise slimseg YOLOv8 models from reference (ultralytics-layout) YOLOv8-seg state dicts.

Training-time initialisation (``slimseg train --weights``): it lives with the trainer.

The reference network is one ``nn.Sequential`` whose tensors are named ``model.{i}.…`` by
layer index (``docs/architecture.md`` §1). Layers are matched by
*structure*: each reference layer index has a fixed place in our backbone / neck / head, and
its tensors are copied only when our module there is of the same kind (a reference C2f never
feeds a VoVGSCSP, a decoupled head never feeds the shared RepConv head) and every shape
agrees. The class predictor can be reduced to a subset of its rows (e.g. the 20 COCO-20
classes out of the 80 COCO ones).

Files are read without unpickling objects: a ``torch.save``'d state dict (optionally nested
under ``"state_dict"`` or ``"model"``) via ``torch.load(weights_only=True)``, or a
``.safetensors`` file when the ``safetensors`` package is installed.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import nn

from slimseg.errors import SlimsegError
from slimseg.layers.conv import ConvBNAct
from slimseg.layers.csp import SPPF, C2f
from slimseg.models.base import ZooModel
from slimseg.models.heads.decode import DistributionFocalDecode
from slimseg.models.heads.decoupled import DecoupledDetect
from slimseg.models.heads.masks import MaskCoefficients, Proto

# COCO 2017 category ids of the 80 "things" classes, in the order of the 80-class predictor
# (1..90 minus the ten ids the 2017 release dropped).
_DROPPED_IDS = frozenset({12, 26, 29, 30, 45, 66, 68, 69, 71, 83})
COCO80_IDS: tuple[int, ...] = tuple(i for i in range(1, 91) if i not in _DROPPED_IDS)

# COCO 2017 category names, same order as ``COCO80_IDS``.
COCO80_NAMES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat",
    "dog", "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack",
    "umbrella", "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball",
    "kite", "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket",
    "bottle", "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple",
    "sandwich", "orange", "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair",
    "couch", "potted plant", "bed", "dining table", "toilet", "tv", "laptop", "mouse",
    "remote", "keyboard", "cell phone", "microwave", "oven", "toaster", "sink",
    "refrigerator", "book", "clock", "vase", "scissors", "teddy bear", "hair drier",
    "toothbrush",
)  # fmt: skip

assert len(COCO80_IDS) == len(COCO80_NAMES) == 80

# Reference layer index → (our module path, the module type it must be to receive it).
# Layers 10, 11, 13, 14, 17 and 20 (upsample / concat) hold no tensors.
_LAYERS: dict[int, tuple[str, type[nn.Module]]] = {
    0: ("backbone.stem.0", ConvBNAct),
    1: ("backbone.stem.1", ConvBNAct),
    2: ("backbone.stem.2", C2f),
    3: ("backbone.stage3.0", ConvBNAct),
    4: ("backbone.stage3.1", C2f),
    5: ("backbone.stage4.0", ConvBNAct),
    6: ("backbone.stage4.1", C2f),
    7: ("backbone.stage5.0", ConvBNAct),
    8: ("backbone.stage5.1", C2f),
    9: ("backbone.stage5.2", SPPF),
    12: ("neck.top_down4", C2f),
    15: ("neck.top_down3", C2f),
    16: ("neck.down3", ConvBNAct),
    18: ("neck.bottom_up4", C2f),
    19: ("neck.down4", ConvBNAct),
    21: ("neck.bottom_up5", C2f),
}
HEAD_INDEX = 22

# Head sub-module of the reference Segment/Detect → (our module path, its type).
_HEAD_PARTS: dict[str, tuple[str, type[nn.Module]]] = {
    "cv2": ("detect.box", DecoupledDetect),
    "cv3": ("detect.cls", DecoupledDetect),
    "cv4": ("mask_coeffs.branches", MaskCoefficients),
    "proto": ("proto", Proto),
    "dfl": ("dfl", DistributionFocalDecode),
}

_REF_KEY = re.compile(r"^model\.(\d+)\.(.+)$")
_CLASS_PREDICTOR = re.compile(r"^cv3\.(\d+)\.2\.(weight|bias)$")

# Skip reasons (the report groups by these).
NO_COUNTERPART = "no counterpart"
SHAPE_MISMATCH = "shape mismatch"
NOT_IN_MODEL = "not in model"
UNKNOWN_LAYER = "unknown reference layer"
CLASSES_NOT_COCO = "classes are not COCO classes"


@dataclass
class Skipped:
    """One reference tensor that was not loaded."""

    key: str
    reason: str
    detail: str = ""


@dataclass
class MappingReport:
    """What ``map_reference_state_dict`` / ``load_pretrained`` did."""

    variant: str
    total: int
    loaded: list[str] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)
    class_rows: list[int] | None = None
    reference_classes: int | None = None
    classes_loaded: bool = False
    model_tensors: int = 0

    @property
    def num_loaded(self) -> int:
        return len(self.loaded)

    def skipped_by_reason(self) -> dict[str, list[Skipped]]:
        groups: dict[str, list[Skipped]] = {}
        for s in self.skipped:
            groups.setdefault(s.reason, []).append(s)
        return groups

    def format(self, examples: int = 5) -> str:
        """Short multi-line summary: loaded count, class rows, skipped tensors by reason."""
        lines = [
            f"pretrained → {self.variant}: loaded {self.num_loaded} of {self.total} reference "
            f"tensors ({self.model_tensors - self.num_loaded} of the model's "
            f"{self.model_tensors} keep their initialisation)"
        ]
        if self.class_rows is not None:
            rows = ", ".join(map(str, self.class_rows))
            of = f" of {self.reference_classes}" if self.reference_classes else ""
            if self.classes_loaded:
                lines.append(f"  class predictor: rows [{rows}]{of}")
            else:
                lines.append(f"  class predictor: not loaded (rows [{rows}]{of} requested)")
        for reason, items in self.skipped_by_reason().items():
            lines.append(f"  skipped ({reason}): {len(items)}")
            for s in items[:examples]:
                lines.append(f"    {s.key}" + (f"  ({s.detail})" if s.detail else ""))
            if len(items) > examples:
                lines.append(f"    … {len(items) - examples} more")
        return "\n".join(lines)


# --------------------------------------------------------------------------- class rows


def coco80_rows_for(coco_ids: Iterable[int]) -> list[int]:
    """COCO 2017 category ids → their rows in the 80-class predictor (person 1 → 0)."""
    index = {cid: row for row, cid in enumerate(COCO80_IDS)}
    rows = []
    for cid in coco_ids:
        if int(cid) not in index:
            raise SlimsegError(f"{cid} is not one of the 80 COCO 2017 category ids")
        rows.append(index[int(cid)])
    return rows


def _normalise_name(name: str) -> str:
    return " ".join(str(name).replace("_", " ").lower().split())


def rows_for_names(names: Sequence[str]) -> list[int] | None:
    """Class names → rows of the 80-class predictor; None if any name is not a COCO name."""
    index = {n: row for row, n in enumerate(COCO80_NAMES)}
    rows = [index.get(_normalise_name(n)) for n in names]
    if not rows or any(r is None for r in rows):
        return None
    return [r for r in rows if r is not None]


# --------------------------------------------------------------------------- mapping


def is_reference_state_dict(state: Mapping[str, object]) -> bool:
    """True if ``state`` is non-empty and every key looks like ``model.{layer index}.…``."""
    return bool(state) and all(isinstance(k, str) and _REF_KEY.match(k) for k in state)


def _variant_name(model: ZooModel) -> str:
    return model.spec.name


def _get_module(model: nn.Module, path: str) -> nn.Module | None:
    try:
        return model.get_submodule(path)
    except AttributeError:
        return None


def _translate_layer(rest: str, kind: type[nn.Module]) -> str:
    """Sub-name inside a backbone/neck layer: only C2f renames (``m.k`` → ``blocks.k``)."""
    if kind is C2f and rest.startswith("m."):
        return "blocks." + rest[2:]
    return rest


def _target(model: nn.Module, layer: int, rest: str, variant: str) -> tuple[str | None, str, str]:
    """Our key for reference ``model.{layer}.{rest}``, or ``(None, reason, detail)``."""
    if layer in _LAYERS:
        path, kind = _LAYERS[layer]
        sub = rest
    elif layer == HEAD_INDEX:
        part, _, sub = rest.partition(".")
        if part not in _HEAD_PARTS:
            return None, NO_COUNTERPART, f"head part {part!r} is not used by {variant}"
        path, kind = _HEAD_PARTS[part]
        if part == "dfl":
            sub = "proj." + sub.partition(".")[2]
    else:
        return None, UNKNOWN_LAYER, f"layer {layer} is not part of YOLOv8-seg"
    owner = path.rsplit(".", 1)[0] if layer == HEAD_INDEX and "." in path else path
    module = _get_module(model, owner)
    if module is None:
        return None, NO_COUNTERPART, f"{variant} has no {owner}"
    if not isinstance(module, kind):
        return None, NO_COUNTERPART, f"{variant}'s {owner} is {type(module).__name__}"
    return f"{path}.{_translate_layer(sub, kind)}", "", ""


def map_reference_state_dict(
    state: Mapping[str, torch.Tensor],
    model: ZooModel,
    class_rows: Sequence[int] | None = None,
    *,
    skip_classes: bool = False,
) -> tuple[dict[str, torch.Tensor], MappingReport]:
    """Rename a reference YOLOv8(-seg) state dict into ``model``'s names, by structure.

    Returns ``(mapped, report)``: ``mapped`` holds every tensor that has a counterpart of the
    same kind and shape in ``model`` (floating tensors cast to the model's dtype), ready for
    ``model.load_state_dict(mapped, strict=False)``. ``class_rows`` selects rows of the class
    predictor (``cv3.{i}.2``) in this order, e.g. ``coco80_rows_for(coco_ids)``; its length
    must equal the model's class count. ``skip_classes=True`` leaves the class predictor
    at its initialisation (the model's classes are not the reference's).
    """
    variant = _variant_name(model)
    if model.is_fused:
        raise SlimsegError(
            f"{variant} is fused (BatchNorm folded); load pretrained weights into the "
            "unfused model, then fuse it"
        )
    ours = model.state_dict()
    rows = None if class_rows is None else [int(r) for r in class_rows]
    report = MappingReport(
        variant=variant, total=len(state), class_rows=rows, model_tensors=len(ours)
    )
    nc = model.num_classes
    if rows is not None and len(rows) != nc:
        raise SlimsegError(f"{len(rows)} class rows given for the {nc}-class {variant}")
    mapped: dict[str, torch.Tensor] = {}
    row_index = torch.tensor(rows, dtype=torch.long) if rows is not None else None
    for key, tensor in state.items():
        m = _REF_KEY.match(key)
        if m is None or not isinstance(tensor, torch.Tensor):
            report.skipped.append(Skipped(key, UNKNOWN_LAYER, "not a model.{i} tensor"))
            continue
        layer, rest = int(m.group(1)), m.group(2)
        is_predictor = layer == HEAD_INDEX and _CLASS_PREDICTOR.match(rest) is not None
        if is_predictor and tensor.dim() >= 1:
            report.reference_classes = int(tensor.shape[0])
        target, reason, detail = _target(model, layer, rest, variant)
        if target is None:
            report.skipped.append(Skipped(key, reason, detail))
            continue
        if is_predictor:
            if skip_classes:
                report.skipped.append(Skipped(key, CLASSES_NOT_COCO, f"→ {target}"))
                continue
            if row_index is not None:
                if rows and max(rows) >= tensor.shape[0]:
                    raise SlimsegError(
                        f"class row {max(rows)} requested but {key} has {tensor.shape[0]} rows"
                    )
                tensor = tensor.index_select(0, row_index)
        if target not in ours:
            report.skipped.append(Skipped(key, NOT_IN_MODEL, f"{variant} has no {target}"))
            continue
        want = ours[target]
        if tuple(tensor.shape) != tuple(want.shape):
            shape = f"{tuple(tensor.shape)} vs {target} {tuple(want.shape)}"
            report.skipped.append(Skipped(key, SHAPE_MISMATCH, shape))
            continue
        if tensor.is_floating_point():
            tensor = tensor.to(dtype=want.dtype)
        mapped[target] = tensor.detach().clone()
        report.loaded.append(target)
        report.classes_loaded |= is_predictor
    return mapped, report


# --------------------------------------------------------------------------- files


def _conversion_hint(path: Path) -> str:
    out = f"{path.stem}.state_dict.pt"
    return (
        f"python -c \"import torch; ckpt = torch.load('{path.name}', weights_only=False); "
        f"torch.save(ckpt['model'].float().state_dict(), '{out}')\""
    )


def _tensor_dict(obj: object) -> dict[str, torch.Tensor] | None:
    if not isinstance(obj, Mapping) or not obj:
        return None
    if all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in obj.items()):
        return dict(obj)
    return None


def read_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """Read a state dict from ``path`` without unpickling arbitrary objects."""
    path = Path(path)
    if not path.is_file():
        raise SlimsegError(f"{path}: weights file not found")
    if path.suffix == ".safetensors":
        try:
            from safetensors.torch import load_file
        except ImportError:
            raise SlimsegError(
                f"{path}: reading .safetensors needs the safetensors package "
                "(pip install safetensors)"
            ) from None
        return load_file(str(path), device="cpu")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickled objects, or not a torch file at all
        raise SlimsegError(
            f"{path}: not a plain state dict ({type(exc).__name__}: pickled objects are not "
            "loaded); convert a reference checkpoint where its package is installed with: "
            + _conversion_hint(path)
        ) from None
    state = _tensor_dict(obj)
    if state is None and isinstance(obj, Mapping):
        for name in ("state_dict", "model"):
            state = _tensor_dict(obj.get(name))
            if state is not None:
                break
    if state is None:
        what = f"keys {list(obj)[:5]}" if isinstance(obj, Mapping) else type(obj).__name__
        raise SlimsegError(
            f"{path}: no state dict of tensors found ({what}); expected a torch.save'd "
            "state dict, optionally under 'state_dict' or 'model'"
        )
    return state


def load_pretrained(
    path: str | Path, model: ZooModel, names: Sequence[str] | None = None
) -> MappingReport:
    """Load a reference YOLOv8(-seg) state dict file into ``model`` (non-strict); the report.

    ``names``: the model's class names. If all are COCO names their rows of the 80-class
    predictor are used (in ``names`` order); otherwise the class predictor is skipped. With
    ``names=None`` the predictor loads as is when its shape matches.
    """
    path = Path(path)
    state = read_state_dict(path)
    if not is_reference_state_dict(state):
        raise SlimsegError(
            f"{path}: not a reference YOLOv8 state dict (keys like 'model.0.conv.weight' "
            f"expected, got e.g. {next(iter(state))!r})"
        )
    rows = rows_for_names(names) if names is not None else None
    skip_classes = names is not None and rows is None
    mapped, report = map_reference_state_dict(state, model, rows, skip_classes=skip_classes)
    _, unexpected = model.load_state_dict(mapped, strict=False)
    assert not unexpected, unexpected
    return report
