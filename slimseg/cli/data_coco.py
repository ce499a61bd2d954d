"""``slimseg data coco-subset | voc2coco | check``: COCO-format dataset preparation commands.

Contract: :func:`add_parsers` registers the three subcommands on an argparse subparsers
object; each sets ``run(args) -> int`` (0 = success, 1 = ``check`` found errors). User
errors raise :class:`~slimseg.errors.SlimsegError` with a one-line message.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from slimseg.cli.arg_types import count
from slimseg.errors import SlimsegError
from slimseg.utils.table import format_table
from slimseg.utils.text import printable


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Register ``coco-subset``, ``voc2coco`` and ``check`` on ``sub``."""
    p = sub.add_parser(
        "coco-subset",
        help="keep a list of COCO classes (e.g. the paper's COCO-20), remapped to ids 1..K",
        description="Write OUT/<name of --ann> with only the classes of --classes, in that "
        "order (category ids 1..K, original id kept as coco_id, mobility prior attached). "
        "Crowd annotations are kept (evaluation only). Images without any kept non-crowd "
        "annotation are dropped unless --keep-unlabeled (use it on val for evaluation on all "
        "images). Images are referenced, not copied.",
    )
    p.add_argument("--ann", required=True, type=Path, help="COCO instances json (input)")
    p.add_argument(
        "--classes",
        required=True,
        type=Path,
        help="classes file 'classes: [{name, coco_id, mobility}]', e.g. configs/data/coco20.yaml",
    )
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument(
        "--keep-unlabeled", action="store_true", help="keep images without kept instances"
    )
    p.add_argument("--images", type=Path, default=None, help="source images folder (recorded)")
    p.set_defaults(run=run_coco_subset)

    p = sub.add_parser(
        "voc2coco",
        help="convert PASCAL VOC XML boxes to a COCO json (boxes only)",
        description="Read Annotations/*.xml of the ids in VOC<year>/ImageSets/Main/<set>.txt. "
        "Boxes become 0-based xywh; no segmentation (the loader uses filled boxes as masks). "
        "file_name is relative to the VOCdevkit folder (use it as the images folder).",
    )
    p.add_argument("--voc-root", required=True, type=Path, help="VOCdevkit folder")
    p.add_argument(
        "--sets",
        nargs="+",
        required=True,
        help="YEAR/SET entries, e.g. 2007/trainval 2012/trainval",
    )
    p.add_argument("--out", required=True, type=Path, help="output COCO json file")
    p.add_argument("--classes", nargs="+", default=None, help="keep only these VOC classes")
    p.add_argument(
        "--difficult",
        choices=("ignore", "train", "drop"),
        default="ignore",
        help="difficult objects: iscrowd=1 ignore regions (default), ordinary instances, or "
        "left out",
    )
    p.add_argument("--keep-unlabeled", action="store_true", help="keep images without kept objects")
    p.set_defaults(run=run_voc2coco)

    p = sub.add_parser(
        "check",
        help="report every problem of a COCO-format dataset (exit 1 on errors)",
        description="Check a data yaml (train and val), a folder with annotations.json + "
        "images/, or a COCO json (--images DIR, default: images/ next to it). Reads every "
        "image. Errors: missing/corrupt images, size mismatch, duplicate ids, unknown "
        "categories, bad segmentations. Warnings: conversions, dropped polygons, clipped boxes.",
    )
    p.add_argument("source", type=Path, help="data yaml, dataset folder or COCO json")
    p.add_argument("--images", type=Path, default=None, help="images folder (json input)")
    p.add_argument("--split", choices=("train", "val"), default=None, help="yaml: one split")
    p.add_argument("--workers", type=count(1), default=8, help="image reading threads")
    p.add_argument("--strict", action="store_true", help="also fail (exit 1) on warnings")
    p.add_argument("--no-info", action="store_true", help="hide info-level rows")
    p.add_argument("--json", action="store_true", help="print JSON (every file) instead")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run_check)


def run_coco_subset(args: argparse.Namespace) -> int:
    from slimseg.data.subset import coco_subset

    out_path, stats = coco_subset(
        args.ann, args.classes, args.out, keep_unlabeled=args.keep_unlabeled, images_dir=args.images
    )
    for w in stats.warnings:
        print(f"warning: {printable(w)}", file=sys.stderr)
    print(
        format_table(
            ["id", "class", "coco_id", "mobility", "instances", "crowd", "images"], stats.rows()
        )
    )
    print(
        f"\nkept {stats.images_out:,}/{stats.images_in:,} images, "
        f"{stats.annotations_out:,}/{stats.annotations_in:,} annotations -> {out_path}"
    )
    return 0


def run_voc2coco(args: argparse.Namespace) -> int:
    from slimseg.data.voc import voc_to_coco
    from slimseg.utils.atomic import write_json

    if args.out.suffix.lower() != ".json":
        raise SlimsegError(f"--out {args.out}: expected a .json file name")
    data, stats = voc_to_coco(
        args.voc_root, args.sets, args.classes, args.difficult, args.keep_unlabeled
    )
    write_json(args.out, data)
    print(format_table(["id", "class", "instances", "difficult"], stats.rows()))
    if stats.bad_boxes:
        print(
            f"warning: skipped {len(stats.bad_boxes)} empty boxes, e.g. "
            + printable(", ".join(stats.bad_boxes[:5])),
            file=sys.stderr,
        )
    print(
        f"\nkept {stats.images_out:,}/{stats.images_in:,} images, "
        f"{len(data['annotations']):,} objects ({stats.other_class:,} of other classes) "
        f"-> {args.out}"
    )
    return 0


def run_check(args: argparse.Namespace) -> int:
    from slimseg.data.check import check_dataset

    if args.workers < 1:
        raise SlimsegError(f"--workers {args.workers}: must be at least 1")
    report = check_dataset(
        args.source,
        images=args.images,
        split=args.split,
        workers=args.workers,
        progress=not (args.quiet or args.json),
    )
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        print(report.format(show_info=not args.no_info))
    failed = report.errors > 0 or (args.strict and report.warnings > 0)
    return 1 if failed else 0
