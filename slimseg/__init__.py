"""slimseg: lightweight detectors and segmenters for dynamic visual SLAM.

The public names are imported on first use (PEP 562), so that importing a torch-free
submodule (the ORB-SLAM3 run process, :mod:`slimseg.data`) does not load torch.

- models: :func:`build_model`, :func:`get_spec`, :func:`list_models`, :func:`fuse`;
- the runtime (docs/runtime_api.md): :class:`Masker` (one object a SLAM loop calls per
  frame), :class:`ModelRate` (how often its model runs), :func:`remove_dynamic` (a masked
  frame as ORB-SLAM3 should see it)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from slimseg.version import __version__

if TYPE_CHECKING:
    from slimseg.deploy.masker import Masker
    from slimseg.dynamic.model_rate import ModelRate
    from slimseg.dynamic.remove_region import remove_dynamic
    from slimseg.layers.fuse import fuse_model as fuse
    from slimseg.models.registry import build_model, get_spec, list_models

__all__ = [
    "Masker",
    "ModelRate",
    "__version__",
    "build_model",
    "fuse",
    "get_spec",
    "list_models",
    "remove_dynamic",
]


def __getattr__(name: str) -> object:
    if name == "fuse":
        from slimseg.layers.fuse import fuse_model

        return fuse_model
    if name in ("build_model", "get_spec", "list_models"):
        from slimseg.models import registry

        return getattr(registry, name)
    if name == "Masker":
        from slimseg.deploy.masker import Masker

        return Masker
    if name == "ModelRate":
        from slimseg.dynamic.model_rate import ModelRate

        return ModelRate
    if name == "remove_dynamic":
        from slimseg.dynamic.remove_region import remove_dynamic

        return remove_dynamic
    raise AttributeError(f"module 'slimseg' has no attribute {name!r}")
