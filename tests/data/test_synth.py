"""The embedded procedural RGB-D dataset: determinism, exact masks, depth, TUM sequences."""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from pycocotools import mask as mask_utils

from slimseg.cli import data_synth
from slimseg.data.synth import (
    CATEGORIES,
    MIN_AREA,
    build_world,
    frame_annotations,
    generate,
    render_image,
    render_sequence_frame,
    write_sequence,
)
from slimseg.data.synth.sequence import placements_at
from slimseg.data.synth.shapes import draw
from slimseg.data.synth.world import FPS
from slimseg.errors import SlimsegError

IMGSZ = 128
# pycocotools' RLE decode trips a numpy 2 deprecation inside the library
pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")


def _files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "ds"
    generate(out, 6, 3, IMGSZ, seed=3, sequences=1, frames=3, seq_size=(128, 96), progress=False)
    return out


def test_layout_and_data_yaml(dataset: Path) -> None:
    cfg = yaml.safe_load((dataset / "data.yaml").read_text())
    assert cfg["path"] == "."
    assert cfg["names"] == [c.name for c in CATEGORIES]
    assert cfg["mobility"] == [c.mobility for c in CATEGORIES]
    assert cfg["names"][0] == "person" and cfg["mobility"][0] == 1.0
    assert set(cfg["mobility"]) <= {0.0, 0.25, 0.5, 0.75, 1.0}
    for split, n in (("train", 6), ("val", 3)):
        entry = cfg[split]
        assert len(list((dataset / entry["images"]).glob("*.png"))) == n
        assert len(list((dataset / entry["depth"]).glob("*.png"))) == n
        coco = json.loads((dataset / entry["annotations"]).read_text())
        assert [c["id"] for c in coco["categories"]] == list(range(1, len(CATEGORIES) + 1))
        assert all("mobility" in c for c in coco["categories"])
        img = cv2.imread(str(dataset / entry["images"] / coco["images"][0]["file_name"]))
        assert img.shape == (IMGSZ, IMGSZ, 3)
        depth = cv2.imread(str(dataset / entry["depth"] / "000000.png"), cv2.IMREAD_UNCHANGED)
        assert depth.dtype == np.uint16 and depth.shape == (IMGSZ, IMGSZ)
    assert not list(dataset.rglob("*.tmp")), "temporary files left behind"


def test_deterministic_per_seed(dataset: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    generate(again, 6, 3, IMGSZ, seed=3, sequences=1, frames=3, seq_size=(128, 96), progress=False)
    a, b = _files(dataset), _files(again)
    assert a.keys() == b.keys()
    assert all(a[k] == b[k] for k in a), [k for k in a if a[k] != b[k]][:5]
    other = tmp_path / "other"
    generate(other, 6, 3, IMGSZ, seed=4, progress=False)
    c = _files(other)
    assert c["train/annotations.json"] != a["train/annotations.json"]
    assert all(c[f"train/images/{i:06d}.png"] != a[f"train/images/{i:06d}.png"] for i in range(6))
    # one image does not depend on the others: rendering in any order gives the same bytes
    assert np.array_equal(render_image(3, 5, IMGSZ).rgb, render_image(3, 5, IMGSZ).rgb)


def test_masks_boxes_and_areas(dataset: Path) -> None:
    coco = json.loads((dataset / "train" / "annotations.json").read_text())
    by_image: dict[int, list[dict]] = {}
    for ann in coco["annotations"]:
        by_image.setdefault(ann["image_id"], []).append(ann)
        assert isinstance(ann["segmentation"]["counts"], str)
        assert ann["iscrowd"] == 0 and 1 <= ann["category_id"] <= len(CATEGORIES)
        m = mask_utils.decode(ann["segmentation"])
        ys, xs = np.nonzero(m)
        box = [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
        assert ann["bbox"] == [float(v) for v in box]
        assert ann["area"] == int(m.sum()) >= MIN_AREA
    assert by_image, "no annotations at all"
    for anns in by_image.values():
        total = sum(mask_utils.decode(a["segmentation"]).astype(int) for a in anns)
        assert total.max() <= 1, "masks of one image overlap"


def test_categories_counts_and_small_instances() -> None:
    seen: set[str] = set()
    for i in range(40):
        frame = render_image(11, i, IMGSZ)
        assert 1 <= len(frame.placements) <= 8
        seen |= {p.style.category for p in frame.placements}
        anns = frame_annotations(frame, i)
        kept = {a["area"] for a in anns}
        areas = [int(frame.mask(j).sum()) for j in range(len(frame.placements))]
        assert len(anns) == sum(a >= MIN_AREA for a in areas)
        assert all(a >= MIN_AREA for a in kept)
    assert "person" in seen and len(seen) >= 4


def test_depth_consistent_with_layering() -> None:
    for i in range(12):
        frame = render_image(7, i, IMGSZ)
        assert frame.depth.dtype == np.uint16
        assert frame.room_depth_m.min() >= 3.0
        for j, p in enumerate(frame.placements):
            m = frame.mask(j)
            if not m.any():
                continue
            assert np.all(frame.depth_m[m] == np.float32(p.depth))
            assert np.all(frame.depth_m[m] < frame.room_depth_m[m])
        for p in frame.placements:  # occlusion: whatever is seen over p's shape is nearer
            patch = draw(p.style, p.cx, p.cy, p.size, IMGSZ, IMGSZ)
            if patch is None:
                continue
            h, w = patch.mask.shape
            region = frame.depth_m[patch.y0 : patch.y0 + h, patch.x0 : patch.x0 + w]
            assert np.all(region[patch.mask > 0] <= np.float32(p.depth))
        valid = frame.depth > 0
        z = frame.depth_m[valid]
        err = np.abs(frame.depth[valid] / 5000.0 - z)
        assert np.all(err <= 3 * z**2 / 320 + 1e-3), "depth noise beyond a few disparity steps"


def test_sequence_files(dataset: Path) -> None:
    seq = dataset / "sequences" / "seq_000"
    rgb_txt = (seq / "rgb.txt").read_text().splitlines()
    depth_txt = (seq / "depth.txt").read_text().splitlines()
    gt = (seq / "groundtruth.txt").read_text().splitlines()
    assert rgb_txt[0] == "# color images" and depth_txt[0] == "# depth maps"
    assert gt[0] == "# ground truth trajectory" and gt[2].endswith("tx ty tz qx qy qz qw")
    rows = [line.split() for line in rgb_txt if not line.startswith("#")]
    drows = [line.split() for line in depth_txt if not line.startswith("#")]
    stamps = [float(r[0]) for r in rows]
    assert len(rows) == 3 and all(b > a for a, b in itertools.pairwise(stamps))
    assert np.allclose(np.diff(stamps), 1 / FPS, atol=2e-6)
    for (t, f), (td, fd) in zip(rows, drows, strict=True):
        assert f == f"rgb/{t}.png" and (seq / f).is_file()
        assert fd == f"depth/{td}.png" and (seq / fd).is_file()
        assert 0.004 < float(td) - float(t) < 0.006
        assert (seq / "dynamic" / f"{t}.png").is_file()
        assert (seq / "background" / "rgb" / f"{t}.png").is_file()
        assert (seq / "background" / "depth" / f"{td}.png").is_file()
    poses = [line.split() for line in gt if not line.startswith("#")]
    assert all(len(p) == 8 for p in poses) and [p[0] for p in poses] == [r[0] for r in rows]
    cam = yaml.safe_load((seq / "camera.yaml").read_text())
    assert cam["depth_scale"] == 5000.0 and {"fx", "fy", "cx", "cy"} <= cam.keys()
    coco = json.loads((seq / "annotations.json").read_text())
    assert len(coco["images"]) == 3


def test_sequence_dynamic_masks_and_background(tmp_path: Path) -> None:
    write_sequence(tmp_path, seed=2, index=0, frames=4, size=(160, 120))
    coco = json.loads((tmp_path / "annotations.json").read_text())
    images = {im["id"]: im for im in coco["images"]}
    moving_seen = 0
    for ann in coco["annotations"]:
        name = Path(images[ann["image_id"]]["file_name"]).name
        dyn = cv2.imread(str(tmp_path / "dynamic" / name), cv2.IMREAD_UNCHANGED)
        m = mask_utils.decode(ann["segmentation"]) > 0
        if ann["moving"]:
            moving_seen += 1
            assert ann["category_id"] == 1 and np.all(dyn[m] == 255)
        else:
            assert not np.any(dyn[m])
    assert moving_seen > 0
    world = build_world(2, 0, 4, 160, 120)
    for i in range(4):
        sf = render_sequence_frame(world, i)
        moving = [j + 1 for j, p in enumerate(sf.frame.placements) if p.moving]
        assert all(p.style.category == "person" for p in sf.frame.placements if p.moving)
        assert np.array_equal(sf.dynamic > 0, np.isin(sf.frame.labels, moving))
        differs = (sf.frame.rgb != sf.background_rgb).any(2) | (
            sf.frame.depth != sf.background_depth
        )
        assert not (differs & (sf.dynamic == 0)).any()


def test_camera_motion_gives_parallax() -> None:
    world = build_world(0, 0, 60, 320, 240)
    a = {p.track_id: p for p in placements_at(world, world.pose(0), 0.0) if not p.moving}
    b = {p.track_id: p for p in placements_at(world, world.pose(59), 59 / FPS) if not p.moving}
    common = sorted(a.keys() & b.keys(), key=lambda t: a[t].depth)
    near, far = common[0], common[-1]
    assert a[far].depth - a[near].depth > 0.5
    shift_near = b[near].cx - a[near].cx
    shift_far = b[far].cx - a[far].cx
    assert abs(shift_near - shift_far) > 1.0
    # apparent size follows 1 / depth
    for t in common:
        assert a[t].size * a[t].depth == pytest.approx(b[t].size * b[t].depth, rel=0.02)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    data_synth.add_parser(parser.add_subparsers(dest="command"))
    return parser


def test_cli_defaults_run_and_user_errors(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    parser = _parser()
    d = parser.parse_args(["synth", "--out", str(tmp_path / "x")])
    assert (d.train, d.val, d.imgsz, d.seed, d.sequences, d.frames) == (512, 128, 320, 0, 0, 60)
    out = tmp_path / "cli"
    args = parser.parse_args(
        ["synth", "--out", str(out), "--train", "2", "--val", "1", "--imgsz", "64", "--quiet"]
    )
    assert args.run(args) == 0
    assert "data.yaml" in capsys.readouterr().out and (out / "data.yaml").is_file()
    bad = [
        ["--out", str(out), "--train", "1", "--val", "1", "--imgsz", "64"],  # not empty
        ["--out", str(tmp_path / "a"), "--imgsz", "100"],
        ["--out", str(tmp_path / "b"), "--train", "0"],  # one split without the other
        ["--out", str(tmp_path / "c"), "--train", "0", "--val", "0"],  # nothing at all
    ]
    for argv in bad:
        args = parser.parse_args(["synth", *argv])
        with pytest.raises(SlimsegError):
            args.run(args)
    args = parser.parse_args(["synth", *bad[0], "--overwrite", "--quiet"])
    assert args.run(args) == 0
    assert len(list((out / "train" / "images").glob("*.png"))) == 1
