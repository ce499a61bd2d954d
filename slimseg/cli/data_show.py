"""``slimseg data show``: a PNG grid of augmented (or validation) samples."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from slimseg.cli.arg_types import count, multiple_of
from slimseg.errors import SlimsegError
from slimseg.utils.outputs import claim_file, refuse_inputs
from slimseg.utils.text import printable

_PNG = b"\x89PNG\r\n\x1a\n"


def _is_png(path: Path) -> bool:
    """``path`` is a PNG file (what ``data show`` writes), judged by its signature."""
    try:
        if not path.is_file():  # a folder, a FIFO, a device: never a grid of ours
            return False
        with path.open("rb") as f:
            return f.read(len(_PNG)) == _PNG
    except OSError:
        return False


def _refuse_dataset_folders(out: str, cfg: object) -> None:
    """``SlimsegError`` when ``out`` lies in a folder of the dataset, of either split (its
    images, depth or sequence folders): it could replace a file the run does not read."""
    target = Path(out).expanduser().resolve()
    for name in ("train", "val"):
        split = getattr(cfg, name)
        if split is None:
            continue
        for folder in (split.images, split.depth, *split.sequences):
            if folder is not None and Path(folder).resolve() in target.parents:
                raise SlimsegError(f"--out {out} lies in the dataset's {name} folder {folder}: "
                                   "write it elsewhere")  # fmt: skip


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "show",
        help="write a PNG grid of augmented samples with masks and boxes",
        description="Draw samples as the trainer sees them (mosaic, affine, HSV, flip; or the "
        "validation letterbox with --val): tinted masks, boxes, class names.",
    )
    p.add_argument("--data", required=True, help="dataset config YAML")
    p.add_argument("--augment", default=None, help="augmentation YAML (default: recipe defaults)")
    p.add_argument("--imgsz", type=multiple_of(), default=320)
    p.add_argument("--count", type=count(1), default=16, help="number of samples")
    p.add_argument("--columns", type=count(1), default=4)
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--val", action="store_true", help="show the validation split, letterbox only")
    p.add_argument("--out", default="runs/data_show.png", help="output PNG")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    # here, not at the top: `slimseg data <other>` needs none of the training stack
    from slimseg.data.augment import load_augment_config
    from slimseg.data.coco import CocoDataset
    from slimseg.data.config import load_data_config
    from slimseg.data.dataset import ZooDataset
    from slimseg.data.visualize import draw_sample, tile
    from slimseg.utils.atomic import write_png

    cfg = load_data_config(args.data)
    split = "val" if args.val else "train"
    base = CocoDataset.from_config(cfg, split)
    augment = None if args.val else load_augment_config(args.augment)
    refuse_inputs(
        args.out,
        "--out",
        {
            "--data": args.data,
            "--augment": args.augment,
            "annotations": base.annotations_json,
            "image": [base.image_path(i) for i in range(len(base))],
        },
    )
    _refuse_dataset_folders(args.out, cfg)
    if base.report["path_outside_root"]:
        ex = ", ".join(printable(e) for e in base.report.examples["path_outside_root"][:3])
        raise SlimsegError(
            f"{base.annotations_json}: path_outside_root: {base.report['path_outside_root']} "
            f"image entries name a file outside the images folder ({ex}): fix their file_name"
        )
    claim_file(args.out, "--out", _is_png, "PNG")  # a grid of an earlier run, not a user's file
    ds = ZooDataset(base, args.imgsz, augment, seed=args.seed)
    count = min(args.count, len(ds))
    if count == 0:
        why = base.report.summary().replace("\n", "; ") or "it lists none"
        raise SlimsegError(f"{args.data}: its {split} split has no usable image to show ({why})")
    panels = [draw_sample(ds[i], cfg.names) for i in range(count)]
    out = write_png(Path(args.out), tile(panels, args.columns))
    kind = "validation (letterbox)" if args.val else "augmented training"
    if base.report.summary():
        print(base.report.summary(), file=sys.stderr)  # images skipped, and why
    print(f"wrote {count} {kind} samples of {args.data} to {out}")
    return 0
