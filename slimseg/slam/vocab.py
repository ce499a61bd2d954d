"""A DBoW2 text vocabulary of ORB descriptors, built from a user's own frames.

ORB-SLAM3 needs a bag-of-words vocabulary (place recognition, relocalisation, and the
keyframe matching it does while tracking). The official ``ORBvoc.txt`` was trained on a large
image collection; offline there is none to download, so :func:`build_vocabulary` trains a small
one: a k-ary tree of binary cluster centres (``k`` children per node, ``levels`` deep), each
level split by k-majority clustering (k-means with Hamming distance and bitwise-majority
centres, seeded k-means++ style), leaves weighted by inverse document frequency.

Text format read by DBoW2's ``loadFromTextFile`` (as ORB-SLAM ships it): a header line
``k L scoring weighting`` (``0 0``: L1 score, TF-IDF), then one line per tree node except the
root, parents before children: ``parent_id is_leaf b0 … b31 weight`` (the 32 descriptor bytes
as decimal integers). Node ids are line numbers (root = 0). :func:`check_vocabulary` validates
a file before it reaches ORB-SLAM3, which terminates the process on a malformed one.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.data.images import decode_file
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_text

log = logging.getLogger(__name__)

DESCRIPTOR_BYTES = 32  # ORB: 256 bits
L1_SCORING, TF_IDF = 0, 0  # DBoW2 enum values in the header
_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], np.uint8)
CHECK_LINES = 2000  # nodes validated at the start of a file (all of a small one)


@dataclass(frozen=True)
class VocabularyInfo:
    """What a vocabulary file declares: branching ``k``, depth ``levels``, node and word
    (leaf) counts; ``official``: the header and size of the ORB-SLAM distribution's file."""

    path: Path
    k: int
    levels: int
    nodes: int
    words: int

    @property
    def official(self) -> bool:
        return self.path.name == "ORBvoc.txt" and self.k == 10 and self.levels == 6

    @property
    def label(self) -> str:
        kind = "official ORBvoc.txt" if self.official else "non-official (slimseg slam vocab)"
        return f"{kind}, k={self.k} L={self.levels}, {self.words} words"


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances between ``a uint8 [N, 32]`` and ``b uint8 [K, 32]`` → ``int32 [N, K]``."""
    out = np.empty((len(a), len(b)), np.int32)
    for j in range(len(b)):
        out[:, j] = _POPCOUNT[np.bitwise_xor(a, b[j])].sum(1, dtype=np.int32)
    return out


def _majority(desc: np.ndarray) -> np.ndarray:
    """Bitwise majority of ``desc uint8 [N, 32]`` → one ``uint8 [32]`` centre (ties → 0)."""
    bits = np.unpackbits(desc, axis=1)
    return np.packbits(2 * bits.sum(0, dtype=np.int64) > len(desc))


def k_majority(
    desc: np.ndarray, k: int, rng: np.random.Generator, iters: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """Cluster ``desc uint8 [N, 32]`` into ≤ ``k`` groups: ``centres uint8 [k', 32]`` and the
    label of each descriptor ``int64 [N]``. Seeds by k-means++ (distance-weighted sampling)."""
    n = len(desc)
    if n <= k:
        return desc.copy(), np.arange(n)
    centres = [desc[int(rng.integers(n))]]
    dmin = hamming(desc, centres[0][None])[:, 0].astype(np.float64)
    for _ in range(1, k):
        total = (dmin**2).sum()
        if total == 0:
            break
        c = desc[int(rng.choice(n, p=dmin**2 / total))]
        centres.append(c)
        dmin = np.minimum(dmin, hamming(desc, c[None])[:, 0])
    cent = np.stack(centres)
    labels = np.full(n, -1)
    for _ in range(iters):
        new = hamming(desc, cent).argmin(1)
        if np.array_equal(new, labels):
            break
        labels = new
        keep = [j for j in range(len(cent)) if (labels == j).any()]
        cent = np.stack([_majority(desc[labels == j]) for j in keep])
        labels = hamming(desc, cent).argmin(1)
    return cent, labels


def orb_descriptors(
    paths: list[Path] | list[np.ndarray], per_image: int = 1000
) -> tuple[np.ndarray, np.ndarray]:
    """ORB descriptors of every image (a file, or a ``uint8 [H, W]`` grey frame; ORB-SLAM's
    defaults: 8 levels, scale 1.2): ``uint8 [N, 32]`` and the index of the source image
    ``int64 [N]``. Unreadable files raise."""
    orb = cv2.ORB_create(nfeatures=per_image, scaleFactor=1.2, nlevels=8)
    descs, owners = [], []
    for i, p in enumerate(tqdm(paths, desc="ORB", unit="img", disable=len(paths) < 20)):
        gray = p if isinstance(p, np.ndarray) else decode_file(p, cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise SlimsegError(f"cannot read image {p} (slimseg slam vocab --images)")
        _, d = orb.detectAndCompute(gray, None)
        if d is not None:
            descs.append(d)
            owners.append(np.full(len(d), i))
    if not descs:
        raise SlimsegError("no ORB features in the given images: nothing to build a vocabulary")
    return np.concatenate(descs), np.concatenate(owners)


#: A short sequence's own vocabulary (the demo's SLAM stage, the calibration's confirmation):
#: slimseg slam vocab's branching and depth, from at most this many evenly spaced frames.
SMALL_K, SMALL_LEVELS, SMALL_IMAGES = 10, 4, 40


def small_vocabulary(
    images: list[Path] | list[np.ndarray], out: Path, seed: int = 0
) -> VocabularyInfo:
    """The vocabulary of a short sequence from at most :data:`SMALL_IMAGES` of its ``images``
    (files or frames, evenly spaced), written to ``out``."""
    images = images[:: max(1, len(images) // SMALL_IMAGES)]
    return build_vocabulary(images, out, SMALL_K, SMALL_LEVELS, seed=seed)


def build_vocabulary(
    paths: list[Path] | list[np.ndarray],
    out: Path,
    k: int = 10,
    levels: int = 4,
    per_image: int = 1000,
    seed: int = 0,
) -> VocabularyInfo:
    """Train a ``k``-ary, ``levels``-deep vocabulary on the ORB descriptors of ``paths`` and
    write it to ``out`` (DBoW2 text format, atomically). Leaves get idf = ln(images / images
    containing the word). Returns what :func:`check_vocabulary` reads back."""
    if not 2 <= k <= 20 or not 1 <= levels <= 10:
        raise SlimsegError(f"vocabulary shape k={k}, L={levels}: DBoW2 needs 2≤k≤20, 1≤L≤10")
    if not paths:
        raise SlimsegError("slimseg slam vocab: --images matched no file")
    desc, owner = orb_descriptors(paths, per_image)
    rng = np.random.default_rng(seed)
    # nodes: (parent, centre, member indices); BFS order keeps parents before children
    nodes: list[tuple[int, np.ndarray, np.ndarray, int]] = []  # parent, centre, members, depth
    queue = [(0, np.arange(len(desc)), 0)]
    while queue:
        parent, members, depth = queue.pop(0)
        cent, labels = k_majority(desc[members], k, rng)
        for j in range(len(cent)):
            sub = members[labels == j]
            nodes.append((parent, cent[j], sub, depth + 1))
            if depth + 1 < levels and len(sub) > 1:
                queue.append((len(nodes), sub, depth + 1))
    children = {p for p, *_ in nodes}
    n_images = len(paths)
    lines = [f"{k} {levels} {L1_SCORING} {TF_IDF}"]
    words = 0
    for nid, (parent, centre, members, _) in enumerate(nodes, 1):
        leaf = nid not in children
        weight = 0.0
        if leaf:
            words += 1
            weight = float(np.log(n_images / max(len(np.unique(owner[members])), 1)))
        lines.append(f"{parent} {int(leaf)} {' '.join(map(str, centre.tolist()))} {weight:.6f}")
    write_text(out, "\n".join(lines))  # no trailing newline: DBoW2 would read an empty node
    log.info("vocabulary %s: %d descriptors, %d nodes, %d words", out, len(desc), len(nodes), words)
    return check_vocabulary(out)


def check_vocabulary(path: str | Path, max_lines: int = CHECK_LINES) -> VocabularyInfo:
    """Validate a DBoW2 text vocabulary (header; the first ``max_lines`` node lines; node and
    word counts from the rest) and return its :class:`VocabularyInfo`. Raises
    ``SlimsegError`` naming the file and line: ORB-SLAM3 itself exits the process on a bad
    file instead of raising."""
    path = Path(path)
    if not path.is_file():
        raise SlimsegError(
            f"vocabulary {path} does not exist (--vocab ORBvoc.txt, or build "
            "one: slimseg slam vocab --images 'seq/rgb/*.png' --out voc.txt)"
        )
    if path.suffix == ".bin" or path.name.endswith(".tar.gz"):
        raise SlimsegError(f"vocabulary {path}: give the extracted text file (ORBvoc.txt)")
    nodes = words = 0
    try:
        with path.open(encoding="ascii") as f:
            head = f.readline().split()
            try:
                k, levels, scoring, weighting = (int(v) for v in head)
            except ValueError:
                raise SlimsegError(
                    f"{path}:1: expected a DBoW2 header 'k L scoring weighting', got "
                    f"{' '.join(head)[:60]!r}"
                ) from None
            if not (
                0 < k <= 20 and 1 <= levels <= 10 and 0 <= scoring <= 5 and 0 <= weighting <= 3
            ):
                raise SlimsegError(f"{path}:1: header values out of DBoW2's range: {head}")
            internal: set[int] = set()  # nodes declared non-leaf ...
            parents: set[int] = set()  # ... and the nodes some line names as its parent
            for no, line in enumerate(f, 2):
                if not line.strip():
                    raise SlimsegError(f"{path}:{no}: empty line (DBoW2 reads it as a node)")
                nodes += 1
                check = _check_node if nodes <= max_lines else _check_node_shape
                parent, leaf = check(path, no, line, nodes)
                words += leaf
                if not leaf:
                    internal.add(nodes)
                parents.add(parent)
            childless = sorted(internal - parents)
            if childless:
                raise SlimsegError(
                    f"vocabulary {path}: {len(childless)} inner node(s) without children (first: "
                    f"node {childless[0]}, line {childless[0] + 1}): the file is truncated or "
                    "was edited; copy or extract it again"
                )
    except UnicodeDecodeError:
        raise SlimsegError(f"vocabulary {path} is not a text file (DBoW2 text format)") from None
    except OSError as e:
        raise SlimsegError(f"cannot read vocabulary {path}: {e}") from None
    if words == 0:
        raise SlimsegError(f"vocabulary {path} has no words (leaf nodes)")
    return VocabularyInfo(path, k, levels, nodes, words)


def _check_node_shape(path: Path, no: int, line: str, nid: int) -> tuple[int, bool]:
    """A node line's field count, parent, leaf flag and weight (a finite number >= 0); the
    descriptor bytes are left to :func:`_check_node` (the first lines only: they cost most).
    Returns the parent id and whether the node is a leaf (a word)."""
    parts = line.split()
    try:
        parent, leaf, weight = int(parts[0]), int(parts[1]), float(parts[-1])
        if (
            len(parts) != 3 + DESCRIPTOR_BYTES
            or not 0 <= parent < nid
            or leaf not in (0, 1)
            or not (math.isfinite(weight) and weight >= 0)
        ):
            raise ValueError
    except (ValueError, IndexError):
        raise SlimsegError(
            f"{path}:{no}: expected 'parent is_leaf <32 bytes> weight' with parent < {nid} "
            "and a finite weight >= 0"
        ) from None
    return parent, leaf == 1


def _check_node(path: Path, no: int, line: str, nid: int) -> tuple[int, bool]:
    """:func:`_check_node_shape` and the 32 descriptor bytes."""
    parent, leaf = _check_node_shape(path, no, line, nid)
    parts = line.split()
    try:
        if not all(0 <= int(v) < 256 for v in parts[2:-1]):
            raise ValueError
    except ValueError:
        raise SlimsegError(f"{path}:{no}: descriptor bytes must be whole numbers 0..255") from None
    return parent, leaf
