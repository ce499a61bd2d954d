"""YOLOv8 compound scaling: channel widths and block repeats from (depth, width, max_channels)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Scaler:
    """Maps the reference (scale-1.0) channel counts and repeats to a model scale."""

    depth: float
    width: float
    max_channels: int

    def channels(self, c: int) -> int:
        """``ceil_to_8(min(c, max_channels) · width)``."""
        return int(math.ceil(min(c, self.max_channels) * self.width / 8) * 8)

    def repeats(self, n: int) -> int:
        """``max(round(n · depth), 1)``."""
        return max(round(n * self.depth), 1)
