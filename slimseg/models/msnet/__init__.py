"""MSNET (VTD-SLAM's transformer semantic segmenter): see :mod:`slimseg.models.msnet.model`."""

from slimseg.models.msnet.model import MSNet

__all__ = ["MSNet"]
