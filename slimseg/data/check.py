"""``slimseg data check``: find every problem of a COCO-format dataset in one pass.

Input (``check_dataset(source)``):

* a dataset yaml (``.yaml``/``.yml``, see :mod:`slimseg.data.config`): its train and val
  splits (with their names; depth folders too);
* a folder holding ``annotations.json`` and ``images/`` (one split, named ``dataset``);
* a COCO json file, with ``images`` the folder its ``file_name``s are relative to
  (default: an ``images/`` folder next to the json).

The same rules as :class:`~slimseg.data.coco.CocoDataset` are applied (kinds and levels in
:data:`slimseg.data.coco.KINDS`), plus what only reading every file reveals: missing,
corrupt or unsupported images, grayscale / RGBA / 16-bit images (converted: warnings),
json size different from the file, missing or bad depth maps, and masks that rasterise to
no pixel. Errors are what the loader cannot handle or what silently loses labels or breaks
evaluation; warnings are what the loader fixes (converts, clips, drops) on its own.
"""

from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from slimseg.data.coco_index import CocoIndex, ImageRecord, build_index, load_coco_json
from slimseg.data.coco_rle import instance_area
from slimseg.data.config import DataConfig, load_data_config
from slimseg.data.images import depth_path_for, read_depth, read_image_rgb8
from slimseg.data.problems import ERROR, INFO, KINDS, WARNING, ImageProblem, LoadReport, kind_level
from slimseg.data.sequence_split import merge_split
from slimseg.errors import SlimsegError
from slimseg.utils.table import format_table
from slimseg.utils.text import printable

_LEVEL_ORDER = {ERROR: 0, WARNING: 1, INFO: 2}


@dataclass
class SplitCheck:
    """The problems of one split and how much was checked."""

    name: str
    images_dir: Path
    annotations: Path
    report: LoadReport
    num_images: int = 0
    num_annotations: int = 0


@dataclass
class CheckReport:
    """Problems per split: ``splits[i].report`` counts kinds and lists *every* location."""

    source: Path
    splits: list[SplitCheck] = field(default_factory=list)

    def count(self, level: str) -> int:
        """Total occurrences of all kinds of ``level`` (``error``/``warning``/``info``)."""
        return sum(s.report.level_counts()[level] for s in self.splits)

    @property
    def errors(self) -> int:
        return self.count(ERROR)

    @property
    def warnings(self) -> int:
        return self.count(WARNING)

    @property
    def ok(self) -> bool:
        """``True`` when no error was found (warnings allowed)."""
        return self.errors == 0

    def kinds(self, split: str | None = None) -> dict[str, int]:
        """Count per kind, summed over splits (or for one split)."""
        out: dict[str, int] = {}
        for s in self.splits:
            if split is None or s.name == split:
                for kind, n in s.report.items():
                    out[kind] = out.get(kind, 0) + n
        return out

    def files(self, kind: str) -> list[str]:
        """Every location reported for ``kind`` (all splits)."""
        return [f for s in self.splits for f in s.report.examples.get(kind, [])]

    def rows(self, levels: tuple[str, ...] = (ERROR, WARNING, INFO)) -> list[list[object]]:
        """Table rows: split, level, kind, count, up to 5 example locations."""
        rows = []
        for s in self.splits:
            items = [(k, n) for k, n in s.report.items() if n and kind_level(k) in levels]
            items.sort(key=lambda kn: (_LEVEL_ORDER[kind_level(kn[0])], kn[0]))
            for kind, n in items:
                ex = s.report.examples.get(kind, [])
                more = f" (+{len(ex) - 5} more)" if len(ex) > 5 else ""
                rows.append([s.name, kind_level(kind), kind, n, ", ".join(ex[:5]) + more])
        return rows

    def format(self, show_info: bool = True) -> str:
        """A plain-text table of every kind found and a one-line verdict."""
        levels = (ERROR, WARNING, INFO) if show_info else (ERROR, WARNING)
        lines = []
        for s in self.splits:
            lines.append(
                f"{s.name}: {s.num_images:,} images, {s.num_annotations:,} annotations "
                f"({s.annotations}; images in {s.images_dir})"
            )
        rows = self.rows(levels)
        if rows:
            lines += ["", format_table(["split", "level", "kind", "count", "examples"], rows)]
            used = sorted({str(r[2]) for r in rows}, key=lambda k: (_LEVEL_ORDER[kind_level(k)], k))
            lines += ["", *(f"  {k}: {KINDS[k][1]}" for k in used if k in KINDS)]
        verdict = "FAILED" if self.errors else "OK"
        lines += ["", f"{verdict}: {self.errors:,} errors, {self.warnings:,} warnings"]
        return printable("\n".join(lines), newlines=True)  # file names come from the json

    def to_dict(self) -> dict:
        """JSON-ready form: per split, per kind, level, count and every location."""
        return {
            "source": str(self.source),
            "errors": self.errors,
            "warnings": self.warnings,
            "splits": [
                {
                    "name": s.name,
                    "images_dir": str(s.images_dir),
                    "annotations": str(s.annotations),
                    "num_images": s.num_images,
                    "num_annotations": s.num_annotations,
                    "kinds": {
                        k: {"level": kind_level(k), "count": n, "files": s.report.examples.get(k)}
                        for k, n in sorted(s.report.items())
                    },
                }
                for s in self.splits
            ],
        }


def _targets(
    source: DataConfig | str | Path, images: str | Path | None, split: str | None
) -> tuple[Path, list[tuple[str, Path, Path, Path | None, dict | None]], tuple[str, ...] | None]:
    """(source path, [(split name, images dir, json, depth dir, merged json)], names) of a
    check input; the merged json (else None) of a split read from sequences, whose ``json``
    is then the yaml."""
    if isinstance(source, DataConfig) or Path(source).suffix.lower() in (".yaml", ".yml"):
        cfg = source if isinstance(source, DataConfig) else load_data_config(source)
        wanted = [split] if split else [s for s in ("train", "val") if getattr(cfg, s)]
        if not wanted:  # a yaml without splits lists sequences (slimseg.data.config)
            raise SlimsegError(
                f"{cfg.source}: no train/val image split to check (it lists only the TUM "
                f"sequences {', '.join(cfg.sequences)}, which 'slimseg dynamic' reads)"
            )
        out = []
        for name in wanted:
            s = cfg.split(name)
            if s.sequences:  # one merged json over the split's parts (data.sequence_split)
                root, data = merge_split(s.parts, f"{cfg.source}: '{name}'")
                out.append((name, root, cfg.source, None, data))
            else:
                out.append((name, s.images, s.annotations, s.depth, None))
        return cfg.source, out, cfg.names
    path = Path(source).expanduser()
    if path.is_dir():
        ann, img_dir = path / "annotations.json", path / "images"
        if not ann.is_file():
            raise SlimsegError(f"{path}: no annotations.json (expected annotations.json + images/)")
    elif path.is_file():
        ann, img_dir = path, path.parent / "images"
    else:
        raise SlimsegError(f"{path}: not found (give a data yaml, a folder or a COCO json)")
    if images is not None:
        img_dir = Path(images).expanduser()
    if not img_dir.is_dir():
        raise SlimsegError(f"{img_dir}: images folder not found (pass --images DIR)")
    return path, [("dataset", img_dir, ann, None, None)], None


def _check_image(
    rec: ImageRecord, images_dir: Path, depth_dir: Path | None
) -> Iterator[tuple[str, str]]:
    """(kind, location) problems of one image file, its depth map and its decoded masks."""
    try:
        image, notes = read_image_rgb8(images_dir / rec.file_name)
    except ImageProblem as exc:
        yield exc.kind, rec.file_name
        return
    for kind in notes:
        yield kind, rec.file_name
    h, w = image.shape[:2]
    if (w, h) != (rec.width, rec.height):
        yield "size_mismatch", f"{rec.file_name} (json {rec.width}x{rec.height}, file {w}x{h})"
        return
    if depth_dir is not None:
        try:
            read_depth(depth_path_for(depth_dir, rec.file_name), h, w)
        except ImageProblem as exc:
            yield exc.kind, rec.file_name
    for inst in rec.instances:
        if instance_area(inst, h, w) == 0:
            yield "empty_mask", f"{rec.file_name} (ann {inst.ann_id})"


def _check_split(
    name: str,
    images_dir: Path,
    ann: Path,
    depth_dir: Path | None,
    names: tuple[str, ...] | None,
    workers: int,
    progress: bool,
    merged: dict | None = None,
) -> SplitCheck:
    report = LoadReport(max_examples=None)
    data = load_coco_json(ann) if merged is None else merged
    try:
        index: CocoIndex = build_index(data, names, report, ann)
    except SlimsegError as exc:
        report.add("names_mismatch", str(exc))
        index = build_index(data, None, report, ann)
    result = SplitCheck(name, images_dir, ann, report, len(index.images), len(data["annotations"]))
    del data
    bar = tqdm(total=len(index.images), desc=f"check {name}", unit="img", disable=not progress)
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        jobs = pool.map(lambda r: list(_check_image(r, images_dir, depth_dir)), index.images)
        for problems in jobs:
            for kind, where in problems:
                report.add(kind, where)
            bar.update()
    bar.close()
    return result


def check_dataset(
    source: DataConfig | str | Path,
    images: str | Path | None = None,
    split: str | None = None,
    workers: int = 8,
    progress: bool = True,
) -> CheckReport:
    """Check a dataset (yaml, folder or json: see the module docstring); never stops early.

    Raises SlimsegError only when the input itself cannot be opened (missing yaml or json,
    json that is not COCO). ``workers`` threads read images; ``progress`` shows a tqdm bar.
    """
    src, targets, names = _targets(source, images, split)
    report = CheckReport(src)
    for name, img_dir, ann, depth, merged in targets:
        report.splits.append(
            _check_split(name, img_dir, ann, depth, names, workers, progress, merged)
        )
    return report
