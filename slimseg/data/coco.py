"""COCO-format instance datasets: json index, loading rules and mask decoding.

``CocoDataset(images_dir, annotations_json)`` yields :class:`~slimseg.data.sample.Sample`
objects. The index is built from the json alone at construction (no image is read), so a
dataset of 100k images opens in seconds; images are read on ``__getitem__``.

Loading rules (shared with ``slimseg data check``, which reports the same kinds):

* Images are read with ``cv2.IMREAD_UNCHANGED`` (EXIF orientation is *not* applied: COCO
  annotations refer to the stored pixel grid). Grayscale images are replicated to 3
  channels, RGBA drops the alpha channel (no compositing), 16-bit images are mapped to 8
  bits by ``round(v / 257)`` (full range to full range). Each conversion is counted in
  :attr:`CocoDataset.report`. A missing or undecodable file, or one whose size differs from
  the json's ``width``/``height``, raises :class:`~slimseg.errors.SlimsegError` naming it:
  run ``slimseg data check`` first to find them all at once.
* Segmentations may be polygons (a list of ``[x0, y0, x1, y1, ...]`` parts; several parts
  are merged into one mask), compressed RLE (``counts`` a string) or uncompressed RLE
  (``counts`` a list, column-major). Polygon parts with fewer than 3 points or zero area are
  dropped; an instance left without any part is dropped. RLEs whose ``size`` is not the
  image size are dropped. An instance whose mask decodes to no pixel is dropped.
* An annotation without segmentation (missing key, ``[]`` or ``null``; e.g. converted from
  VOC) is kept as a *box instance*: its mask is the filled box and
  ``sample.meta["box_masks"][i]`` is ``True``.
* Boxes (``bbox`` xywh; derived from the segmentation if absent) are clipped to the image;
  an instance whose box is empty (``w <= 0``/``h <= 0``, or nothing left after clipping) is
  dropped.
* ``iscrowd=1`` regions are never training targets: they go to ``sample.meta["crowd_*"]``
  (for ignore regions and evaluation).
* Category ids map to contiguous indices ``0..K-1``: in ``names`` order (matched by name to
  the json categories) if given, else the json categories sorted by id. Annotations of json
  categories not in ``names`` are skipped (counted as ``category_not_selected``);
  category ids absent from the json categories are dropped (``unknown_category``).

Problems found while indexing are counted at construction; per-image ones (conversions,
empty decoded masks) when the image is first loaded. With a multi-process ``DataLoader``
the latter are counted in the worker copies, so the main process only sees index-time
kinds: ``slimseg data check`` gives the complete picture.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slimseg.data.coco_index import Instance, build_index, load_coco_json
from slimseg.data.coco_rle import decode_instance_masks
from slimseg.data.images import depth_path_for, read_depth, read_image_rgb8
from slimseg.data.problems import ImageProblem, LoadReport
from slimseg.data.sample import Sample
from slimseg.data.sequence_split import merge_split
from slimseg.errors import SlimsegError

if TYPE_CHECKING:
    from slimseg.data.config import DataConfig


def _boxes(insts: list[Instance]) -> np.ndarray:
    return np.asarray([i.box for i in insts], np.float32).reshape(-1, 4)


class CocoDataset:
    """Instances of a COCO-format json as :class:`Sample` objects (torch Dataset protocol).

    ``images_dir / file_name`` is each image's path; ``depth_dir`` (optional) holds a
    ``uint16`` PNG per image at the same relative path with suffix ``.png`` (a missing depth
    file gives ``sample.depth = None`` and a ``missing_depth`` count). See the module
    docstring for the loading rules.

    ``sample.meta``: ``file_name``; ``ann_ids`` ``int64 [N]``; ``box_masks`` ``bool [N]``
    (``True``: no segmentation, mask = filled box); ``crowd_masks`` ``uint8 [M, H, W]``,
    ``crowd_boxes`` ``float32 [M, 4]`` xyxy, ``crowd_classes`` ``int64 [M]`` (iscrowd
    regions, excluded from the targets); ``converted`` (list of conversion kinds).

    Attributes: ``names`` (class names, index = class id), ``cat_ids`` (json category id per
    class), ``report`` (:class:`LoadReport`), ``records`` (the :class:`ImageRecord` list).
    """

    def __init__(
        self,
        images_dir: str | Path,
        annotations_json: str | Path,
        names: Sequence[str] | None = None,
        depth_dir: str | Path | None = None,
        data: dict | None = None,
    ) -> None:
        self.images_dir = Path(images_dir)
        self.annotations_json = Path(annotations_json)
        self.depth_dir = Path(depth_dir) if depth_dir is not None else None
        if not self.images_dir.is_dir():
            raise SlimsegError(f"{self.images_dir}: images folder not found")
        if self.depth_dir is not None and not self.depth_dir.is_dir():
            raise SlimsegError(f"{self.depth_dir}: depth folder not found")
        self.report = LoadReport()
        self._data = data  # kept only when given (a merged split has no json file)
        if data is None:
            data = load_coco_json(self.annotations_json)
        index = build_index(data, names, self.report, self.annotations_json)
        self.records = index.images
        self.names = index.names
        self.cat_ids = index.cat_ids
        self.categories = index.categories
        self._reported: set[int] = set()

    @classmethod
    def from_config(
        cls, config: DataConfig, split: str = "train", depth: bool = True
    ) -> CocoDataset:
        """The ``split`` (``"train"``/``"val"``) of a :class:`~slimseg.data.config.DataConfig`.

        A split that names sequences is merged into one json
        (:func:`~slimseg.data.sequence_split.merge_split`; ``annotations_json`` is then the
        yaml, ``images_dir`` the parts' common folder). ``depth=False`` skips the depth maps
        (training does not read them)."""
        s = config.split(split)
        depth_dir = s.depth if depth else None
        if not s.sequences:
            return cls(s.images, s.annotations, names=config.names, depth_dir=depth_dir)
        root, data = merge_split(s.parts, f"{config.source}: '{split}'")
        return cls(root, config.source, names=config.names, data=data)

    @property
    def ground_truth(self) -> Path | dict:
        """The COCO ground truth for evaluation: the json path, or the merged dict of a
        split read from sequences."""
        return self.annotations_json if self._data is None else self._data

    @property
    def num_classes(self) -> int:
        return len(self.names)

    def __len__(self) -> int:
        return len(self.records)

    def image_path(self, index: int) -> Path:
        """Absolute path of image ``index``."""
        return self.images_dir / self.records[index].file_name

    def __getitem__(self, index: int) -> Sample:
        if index < 0:
            index += len(self.records)
        if not 0 <= index < len(self.records):
            raise IndexError(f"index {index} out of range for {len(self.records)} images")
        rec = self.records[index]
        path = self.images_dir / rec.file_name
        first = index not in self._reported
        self._reported.add(index)
        image, notes = read_image_rgb8(path)
        h, w = image.shape[:2]
        if (w, h) != (rec.width, rec.height):
            raise SlimsegError(
                f"{path}: image is {w}x{h} but {self.annotations_json.name} says "
                f"{rec.width}x{rec.height}; run 'slimseg data check' and fix the json"
            )
        if first:
            for kind in notes:
                self.report.add(kind, rec.file_name)

        decoded = decode_instance_masks(rec.instances, h, w)
        nonempty = decoded.any(axis=(1, 2))
        if first:
            for inst, ok in zip(rec.instances, nonempty, strict=True):
                if not ok:
                    self.report.add("empty_mask", f"{rec.file_name} (ann {inst.ann_id})")
        kept = [inst for inst, ok in zip(rec.instances, nonempty, strict=True) if ok]
        masks = decoded if nonempty.all() else decoded[nonempty]
        crowd_masks = decode_instance_masks(rec.crowd, h, w)

        depth = None
        if self.depth_dir is not None:
            try:
                depth = read_depth(depth_path_for(self.depth_dir, rec.file_name), h, w)
            except ImageProblem as exc:
                if exc.kind != "missing_depth":
                    raise
                if first:
                    self.report.add("missing_depth", rec.file_name)

        return Sample(
            image=image,
            boxes=_boxes(kept),
            classes=np.asarray([i.cls for i in kept], np.int64),
            masks=masks,
            image_id=rec.id,
            path=str(path),
            depth=depth,
            meta={
                "file_name": rec.file_name,
                "ann_ids": np.asarray([i.ann_id for i in kept], np.int64),
                "box_masks": np.asarray([i.segm is None for i in kept], bool),
                "crowd_masks": crowd_masks,
                "crowd_boxes": _boxes(rec.crowd),
                "crowd_classes": np.asarray([c.cls for c in rec.crowd], np.int64),
                "converted": notes,
            },
        )
