"""slimseg: lightweight detectors and segmenters for dynamic visual SLAM.

The model functions are imported on first use (PEP 562), so that importing a torch-free
submodule (the ORB-SLAM3 run process, :mod:`slimseg.data`) does not load torch."""

from __future__ import annotations

from typing import TYPE_CHECKING

from slimseg.version import __version__

if TYPE_CHECKING:
    from slimseg.deploy.masker import Masker
    from slimseg.dynamic.model_rate import ModelRate
    from slimseg.layers.fuse import fuse_model as fuse
    from slimseg.models.registry import build_model, get_spec, list_models

__all__ = ["Masker", "ModelRate", "__version__", "build_model", "fuse", "get_spec", "list_models"]


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
    raise AttributeError(f"module 'slimseg' has no attribute {name!r}")
