"""Model registry: variant name → spec (shipped ``slimseg/configs/models``), ``build_model``."""

from __future__ import annotations

import functools
from pathlib import Path

from torch import nn

from slimseg.models.specs import ModelSpec, SpecError, load_spec
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


def build_from_spec(spec: ModelSpec, fused: bool = False) -> nn.Module:
    """Instantiate the network a spec describes; ``fused=True`` builds the deploy form."""
    if spec.family == "yolov8":
        from slimseg.models.yolo import YOLO

        return YOLO(spec, deploy=fused)
    if spec.family == "msnet":
        from slimseg.models.msnet import MSNet

        return MSNet(spec, deploy=fused)
    from slimseg.models.darknet_yolov3 import Darknet19YOLOv3

    kwargs = {"anchors": spec.anchors} if spec.anchors is not None else {}
    model = Darknet19YOLOv3(num_classes=spec.num_classes, deploy=fused, **kwargs)
    model.spec = spec
    return model


def build_model(name: str | Path, num_classes: int | None = None, fused: bool = False) -> nn.Module:
    """Build variant ``name`` (see ``list_models()``) with ``num_classes`` classes.

    ``fused=True`` builds the inference (BN-folded, RepConv-merged) structure, into which
    the state dict of ``slimseg.fuse(model)`` loads.
    """
    return build_from_spec(get_spec(name, num_classes), fused=fused)
