"""Model registry: variant name → spec (shipped ``slimseg/configs/models``), ``build_model``."""

from __future__ import annotations

import functools
from pathlib import Path

import torch

from slimseg.models.base import ZooModel
from slimseg.models.darknet_yolov3 import Darknet19YOLOv3
from slimseg.models.msnet import MSNet
from slimseg.models.specs import ModelSpec, SpecError, load_spec
from slimseg.models.yolo import YOLO
from slimseg.utils.shipped import shipped_dir


@functools.cache
def _specs() -> dict[str, ModelSpec]:
    config_dir = shipped_dir("models")
    specs: dict[str, ModelSpec] = {}
    for path in sorted(config_dir.glob("*.yaml")):
        spec = load_spec(path)
        if spec.name in specs:
            raise SpecError(f"{path}: duplicate model name {spec.name!r}")
        if spec.name != path.stem:
            raise SpecError(f"{path}: name {spec.name!r} must match the file name {path.stem!r}")
        specs[spec.name] = spec
    if not specs:
        raise SpecError(f"no model specs found in {config_dir}")
    return specs


def list_models() -> list[str]:
    """Names of all registered variants, sorted."""
    return sorted(_specs())


def get_spec(name: str | Path, num_classes: int | None = None) -> ModelSpec:
    """Spec of a registered variant, or of a spec YAML file given by path."""
    if str(name).endswith((".yaml", ".yml")):
        spec = load_spec(name)
    else:
        specs = _specs()
        if name not in specs:
            raise SpecError(f"unknown model {name!r}; valid: {', '.join(sorted(specs))}")
        spec = specs[str(name)]
    return spec.with_classes(num_classes)


# spec.family → the class that builds it (each takes ``(spec, fused=...)``).
BUILDERS: dict[str, type[ZooModel]] = {
    "yolov8": YOLO,
    "msnet": MSNet,
    "darknet-yolov3": Darknet19YOLOv3,
}


def detection_rows(family: str, pred: torch.Tensor) -> torch.Tensor:
    """The eval output of a model of ``family`` → NMS rows ``[B, 4 + nc + nm, A]`` (the
    family's declared :meth:`~slimseg.models.base.ZooModel.detection_rows`). Takes the family
    name, not the model, so ONNX files (whose metadata names it) use the same rule."""
    if family not in BUILDERS:
        raise SpecError(f"family {family!r} is unknown; valid: {', '.join(BUILDERS)}")
    return BUILDERS[family].detection_rows(pred)


def build_from_spec(spec: ModelSpec, fused: bool = False) -> ZooModel:
    """Instantiate the network a spec describes; ``fused=True`` builds the fused form."""
    if spec.family not in BUILDERS:
        raise SpecError(
            f"{spec.name}: family {spec.family!r} has no builder; valid: {', '.join(BUILDERS)}"
        )
    return BUILDERS[spec.family](spec, fused=fused)


def build_model(name: str | Path, num_classes: int | None = None, fused: bool = False) -> ZooModel:
    """Build variant ``name`` (see ``list_models()``) with ``num_classes`` classes.

    ``fused=True`` builds the inference (BN-folded, RepConv-merged) structure, into which
    the state dict of ``slimseg.fuse(model)`` loads.
    """
    return build_from_spec(get_spec(name, num_classes), fused=fused)
