"""The in-memory form of one annotated image, shared by every dataset and transform."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Sample:
    """One image and its instances, before batching.

    ``image``: ``uint8 [H, W, 3]`` RGB. ``boxes``: ``float32 [N, 4]`` xyxy in pixels.
    ``classes``: ``int64 [N]`` contiguous ids ``0..K-1``. ``masks``: ``uint8 [N, H, W]`` with
    1 on the visible pixels of each instance. ``depth``: optional ``uint16 [H, W]`` (TUM: 5000
    = 1 m, 0 = missing). ``image_id`` and ``path`` identify the source.
    """

    image: np.ndarray
    boxes: np.ndarray
    classes: np.ndarray
    masks: np.ndarray
    image_id: int = 0
    path: str = ""
    depth: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.classes)
        h, w = self.image.shape[:2]
        if self.boxes.shape != (n, 4) or self.masks.shape != (n, h, w):
            raise ValueError(
                f"{self.path or self.image_id}: inconsistent sample: image {self.image.shape}, "
                f"boxes {self.boxes.shape}, classes {self.classes.shape}, masks {self.masks.shape}"
            )

    @property
    def num_instances(self) -> int:
        return len(self.classes)
