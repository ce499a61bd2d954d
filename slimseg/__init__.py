"""slimseg: lightweight detectors and segmenters for dynamic visual SLAM.

The model functions are imported on first use (PEP 562), so that importing a torch-free
submodule (the ORB-SLAM3 run process, :mod:`slimseg.data`) does not load torch."""

from __future__ import annotations

from typing import TYPE_CHECKING

from slimseg.version import __version__

if TYPE_CHECKING:
    from slimseg.layers.fuse import fuse_model as fuse
    from slimseg.models.registry import build_model, get_spec, list_models

__all__ = ["__version__", "build_model", "fuse", "get_spec", "list_models"]


def __getattr__(name: str) -> object:
    if name == "fuse":
        from slimseg.layers.fuse import fuse_model

        return fuse_model
    if name in ("build_model", "get_spec", "list_models"):
        from slimseg.models import registry

        return getattr(registry, name)
    raise AttributeError(f"module 'slimseg' has no attribute {name!r}")
