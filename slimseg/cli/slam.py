"""``slimseg slam vocab``: build a DBoW2 ORB vocabulary from frames (offline ORB-SLAM3)."""

from __future__ import annotations

import argparse
import glob
from pathlib import Path

import cv2
import numpy as np

from slimseg.cli.arg_types import count
from slimseg.cli.commands import COMMAND_HELP
from slimseg.data.bags.reader import is_bag
from slimseg.errors import SlimsegError
from slimseg.utils.outputs import claim_file, refuse_inputs


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "slam",
        help=COMMAND_HELP["slam"],
        description="Helpers for the SLAM engines used by slimseg slam-eval.",
    )
    actions = p.add_subparsers(dest="action", metavar="<action>", required=True)
    v = actions.add_parser(
        "vocab",
        help="build a DBoW2 text vocabulary from ORB descriptors of frames",
        description="Cluster the ORB descriptors of the given frames into a k-ary tree of "
        "binary words (k-majority per level, idf weights) and write it in DBoW2's text format, "
        "which ORB-SLAM3 loads like ORBvoc.txt. Results made with it are marked non-official.",
    )
    v.add_argument(
        "--images",
        nargs="+",
        required=True,
        help="image files or glob patterns, or one ROS bag (its colour topic; slimseg[ros])",
    )
    v.add_argument("--rgb-topic", help="bag --images: the colour topic (default: the only one)")
    v.add_argument("--out", type=Path, required=True, help="vocabulary text file to write")
    v.add_argument("--k", type=count(2, 20), default=10, help="children per node (default 10)")
    v.add_argument("--levels", type=count(1, 10), default=4, help="tree depth L (default 4)")
    v.add_argument("--per-image", type=count(1), default=1000, help="ORB features per image")
    v.add_argument("--max-images", type=count(1), default=300, help="evenly subsample to this many")
    v.add_argument("--seed", type=count(0), default=0)
    v.set_defaults(run=run_vocab)


def expand_images(patterns: list[str], max_images: int, out: Path | None = None) -> list[Path]:
    """Files named or matched by ``patterns`` (sorted; unique by the file they resolve to, so a
    symlink loop under ``**`` adds nothing), evenly thinned to at most
    ``max_images``. Raises ``SlimsegError`` when nothing matches or the output ``out`` is one
    of the matches."""
    files: dict[Path, Path] = {}  # real file -> the first path naming it
    for pat in patterns:
        matches = [pat] if Path(pat).is_file() else sorted(glob.glob(pat, recursive=True))
        for m in matches:
            if Path(m).is_file():  # a file reached through several links (a loop) counts once
                files.setdefault(Path(m).resolve(), Path(m))
    if not files:
        raise SlimsegError(f"--images {' '.join(patterns)} matched no file")
    paths = sorted(files.values())
    if out is not None:  # every match, not only those kept: none may be overwritten
        refuse_inputs(out, "--out", {"--images": paths})
    if max_images < 1:
        raise SlimsegError(f"--max-images {max_images} must be at least 1")
    if len(paths) > max_images:
        step = len(paths) / max_images
        paths = [paths[int(i * step)] for i in range(max_images)]
    return paths


def bag_frames(bag: str, rgb_topic: str | None, max_images: int) -> list[np.ndarray]:
    """A bag's colour frames as grey ``uint8 [H, W]``, evenly thinned to ``max_images`` (only
    those decoded)."""
    from slimseg.data.bags.colour_stream import BagColour

    if max_images < 1:
        raise SlimsegError(f"--max-images {max_images} must be at least 1")
    frames = BagColour(bag, rgb_topic)
    n = len(frames.stamps)
    keep = (
        set(range(n)) if n <= max_images else {int(i * n / max_images) for i in range(max_images)}
    )
    return [cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) for _, _, rgb in frames.frames(keep)]


def _is_vocabulary(path: Path) -> bool:
    """``path`` starts with a DBoW2 header line (four integers): a vocabulary to replace."""
    try:
        with open(path, "rb") as f:
            head = f.readline(200).split()
    except OSError:
        return False
    return len(head) == 4 and all(t.isdigit() for t in head)


def run_vocab(args: argparse.Namespace) -> int:
    from slimseg.slam.vocab import build_vocabulary

    if len(args.images) == 1 and is_bag(args.images[0]):
        paths = bag_frames(args.images[0], args.rgb_topic, args.max_images)
    else:
        paths = expand_images(args.images, args.max_images, args.out)
    claim_file(args.out, "--out", _is_vocabulary, "vocabulary")
    info = build_vocabulary(paths, args.out, args.k, args.levels, args.per_image, args.seed)
    print(
        f"vocabulary {info.path}: {len(paths)} images, {info.nodes} nodes, {info.words} words "
        f"(k={info.k}, L={info.levels}; non-official: results made with it are marked so)"
    )
    return 0
