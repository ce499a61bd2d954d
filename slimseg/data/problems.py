"""What can be wrong with a dataset: problem kinds, their levels and the load report.

The loader (``slimseg.data.coco``) and ``slimseg data check`` count the same kinds.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

from slimseg.errors import SlimsegError
from slimseg.utils.text import printable

ERROR, WARNING, INFO = "error", "warning", "info"

#: Every problem kind: (level, what it means and what the loader does).
KINDS: dict[str, tuple[str, str]] = {
    "missing_image": (ERROR, "image file not found"),
    "unreadable_image": (ERROR, "corrupt, unreadable or unsupported image file"),
    "size_mismatch": (ERROR, "json width/height differ from the image file"),
    "duplicate_image_id": (ERROR, "image id used twice (later entries ignored)"),
    "duplicate_annotation_id": (ERROR, "annotation id used twice (breaks COCO evaluation)"),
    "bad_image_entry": (ERROR, "image entry without int id / file_name / width / height"),
    "path_outside_root": (
        ERROR,
        "file_name absolute or climbing out of the images folder with ..: not read "
        "(slimseg --allow-outside-root reads it)",
    ),
    "bad_annotation": (ERROR, "annotation without id / image_id / category_id / usable box"),
    "orphan_annotation": (ERROR, "annotation image_id not among the images (dropped)"),
    "unknown_category": (ERROR, "category_id not among the json categories (dropped)"),
    "bad_segmentation": (ERROR, "segmentation neither polygons nor a valid RLE (dropped)"),
    "names_mismatch": (ERROR, "a configured class name is not among the json categories"),
    "missing_depth": (ERROR, "depth file not found"),
    "bad_depth": (ERROR, "depth file unreadable, not 16-bit single channel, or wrong size"),
    "grayscale_image": (WARNING, "grayscale image converted to RGB"),
    "rgba_image": (WARNING, "image with alpha channel: alpha dropped"),
    "16bit_image": (WARNING, "16-bit image converted to 8 bits"),
    "polygon_few_points": (WARNING, "polygon part with < 3 points dropped"),
    "polygon_zero_area": (WARNING, "zero-area polygon part dropped"),
    "box_clipped": (WARNING, "box extends outside the image: clipped"),
    "box_outside": (WARNING, "box empty or entirely outside the image: annotation dropped"),
    "empty_mask": (WARNING, "mask has no pixel: annotation dropped"),
    "crowd": (INFO, "iscrowd=1 region: kept out of the training targets"),
    "box_only": (INFO, "no segmentation: the filled box is the mask"),
    "category_not_selected": (INFO, "json category not in names: annotation skipped"),
    "image_without_annotations": (INFO, "image without any training instance"),
}


def kind_level(kind: str) -> str:
    """``"error"``, ``"warning"`` or ``"info"`` for a problem kind (unknown kinds: error)."""
    return KINDS.get(kind, (ERROR, ""))[0]


class LoadReport(Counter):
    """Counts per problem kind, plus example locations (file names) per kind.

    A :class:`collections.Counter` (``report["box_clipped"]``) with ``examples[kind]``: the
    first ``max_examples`` locations (``None``: keep all).
    """

    def __init__(self, max_examples: int | None = 5) -> None:
        super().__init__()
        self.max_examples = max_examples
        self.examples: dict[str, list[str]] = {}

    def add(self, kind: str, where: str = "", n: int = 1) -> None:
        """Count ``n`` occurrences of ``kind`` at location ``where`` (a file name)."""
        self[kind] += n
        ex = self.examples.setdefault(kind, [])
        if where and (self.max_examples is None or len(ex) < self.max_examples):
            ex.append(where)

    def level_counts(self) -> dict[str, int]:
        """Total count per level (``error``/``warning``/``info``)."""
        out = {ERROR: 0, WARNING: 0, INFO: 0}
        for kind, n in self.items():
            out[kind_level(kind)] += n
        return out

    def summary(self, levels: Iterable[str] = (ERROR, WARNING)) -> str:
        """One line per kind of the given levels, e.g. for the trainer's log."""
        wanted = set(levels)
        lines = []
        for kind, n in sorted(self.items()):
            if kind_level(kind) in wanted and n:
                ex = ", ".join(self.examples.get(kind, [])[:3])
                lines.append(f"{kind_level(kind)} {kind}: {n}" + (f" (e.g. {ex})" if ex else ""))
        return printable("\n".join(lines), newlines=True)  # file names come from the json


class ImageProblem(SlimsegError):
    """An image (or depth) file that cannot be used; ``kind`` is a :data:`KINDS` key."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind
