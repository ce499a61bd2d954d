"""slimseg: lightweight detectors and segmenters for dynamic visual SLAM."""

from slimseg.layers.fuse import fuse_model as fuse
from slimseg.models.registry import build_model, get_spec, list_models
from slimseg.version import __version__

__all__ = ["__version__", "build_model", "fuse", "get_spec", "list_models"]
