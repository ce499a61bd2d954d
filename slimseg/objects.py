"""One record for a frame's objects, from the model through the track stage to the mask.

:class:`Objects` is columnar: one row per object, every column an array of length ``N``, and
it slices like an array (``objects[keep]`` with an index array, a boolean mask or a slice). The
model's result enters the per-frame chain as one (``slimseg.dynamic.semantic.objects_of``), the
track stage takes and returns one, the masking rules read one and the masked frame hands it
back. Which columns a stage fills: ``docs/conventions.md`` §7.

Plain numpy: no slimseg import, no torch, so any layer and the core install may use it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

SOURCE_DETECTION, SOURCE_COAST, SOURCE_CARRIED = "det", "coast", "carried"
"""Where a row comes from: this frame's detection, a lost track's predicted mask (coasted), a
track carried over a frame the model skipped."""


@dataclass(frozen=True, eq=False)
class Objects:
    """Frame pixels. The objects of one ``hw = (H, W)`` frame, one row each:

    ``boxes float32 [N, 4]`` xyxy; ``scores float32 [N]`` (1 for a semantic map's components,
    0 for predicted masks); ``classes int64 [N]``; ``masks bool [N, H, W]`` (None: a box-only
    model); ``mobility float32 [N]`` (None: each class's prior; the track stage sets the
    track's moving probability); ``track_ids int64 [N]`` (-1: untracked); ``source [N]`` str
    (:data:`SOURCE_DETECTION`, :data:`SOURCE_COAST`, :data:`SOURCE_CARRIED`); ``misses int64
    [N]`` (frames since the track's last detection); ``det_index int64 [N]`` (row among this
    frame's model detections, -1: predicted); ``own_motion bool [N]`` (a late result already
    moved by the object's own measured motion). Columns left out take those defaults."""

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    masks: np.ndarray | None
    hw: tuple[int, int]
    mobility: np.ndarray | None = None
    track_ids: np.ndarray | None = None
    source: np.ndarray | None = None
    misses: np.ndarray | None = None
    det_index: np.ndarray | None = None
    own_motion: np.ndarray | None = None

    def __post_init__(self) -> None:
        boxes = np.asarray(self.boxes, np.float32).reshape(-1, 4)
        n = len(boxes)
        put = object.__setattr__
        put(self, "boxes", boxes)
        put(self, "scores", np.asarray(self.scores, np.float32).reshape(n))
        put(self, "classes", np.asarray(self.classes, np.int64).reshape(n))
        put(self, "hw", (int(self.hw[0]), int(self.hw[1])))
        if self.masks is not None and self.masks.shape != (n, *self.hw):
            raise ValueError(f"masks {list(self.masks.shape)}: expected [{n}, H, W] = "
                             f"{[n, *self.hw]}")  # fmt: skip
        if self.mobility is not None:
            put(self, "mobility", np.asarray(self.mobility, np.float32).reshape(n))
        defaults = {
            "track_ids": (np.full(n, -1, np.int64), np.int64),
            "source": (np.full(n, SOURCE_DETECTION, object), object),
            "misses": (np.zeros(n, np.int64), np.int64),
            "det_index": (np.arange(n, dtype=np.int64), np.int64),
            "own_motion": (np.zeros(n, bool), bool),
        }
        for name, (default, dtype) in defaults.items():
            value = getattr(self, name)
            put(self, name, default if value is None else np.asarray(value, dtype).reshape(n))

    @classmethod
    def empty(cls, hw: tuple[int, int], with_masks: bool = True) -> Objects:
        """No object (``masks bool [0, H, W]`` if ``with_masks``, else None)."""
        masks = np.zeros((0, *hw), bool) if with_masks else None
        return cls(np.zeros((0, 4), np.float32), np.zeros(0), np.zeros(0), masks, hw)

    def __len__(self) -> int:
        return len(self.boxes)

    def __getitem__(self, index: np.ndarray | slice | list[int]) -> Objects:
        """The rows ``index`` selects (an index array, a boolean mask ``[N]``, a slice), in
        that order; an integer is taken as a one-row selection."""
        if isinstance(index, int | np.integer):
            index = [int(index)]
        if not isinstance(index, slice):
            index = np.asarray(index)
            if index.dtype != bool:
                index = index.astype(np.int64).reshape(-1)
        rows = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name != "hw" and value is not None:
                rows[f.name] = value[index]
        return replace(self, **rows)

    @property
    def predicted(self) -> np.ndarray:
        """``bool [N]``: predicted by a track (coasted or carried), not detected this frame."""
        return self.source != SOURCE_DETECTION

    def priors(self, class_mobility: np.ndarray) -> np.ndarray:
        """``float32 [N]``: the mobility column, or each row's class prior from
        ``class_mobility [K]`` where the column is unset."""
        if self.mobility is not None:
            return self.mobility
        return np.asarray(class_mobility, np.float32)[self.classes]
